"""The CPF's pseudo-random number generator, written with the exact semantics of its C twin.

The generated C (the filter's step partial) and this module produce the same 32-bit integer
stream for the same seed, and in double precision the same uniforms and Gaussian samples bit
for bit (the conversions below are exact, and Box-Muller uses libm's log/sqrt/cos/sin through
Python's `math` module, i.e. the same glibc functions the host C calls).

Generator: xoshiro128** 1.1 (Blackman & Vigna, 2018), 128-bit state s[0..3] (uint32):

    result = rotl(s1 * 5, 7) * 9            (all mod 2^32)
    t  = s1 << 9
    s2 ^= s0;  s3 ^= s1;  s1 ^= s2;  s0 ^= s3;  s2 ^= t;  s3 = rotl(s3, 11)

Seeding from one uint32 `seed` (SplitMix32-style, MurmurHash3's fmix32 on a Weyl sequence):

    x = seed
    for i in 0..3:
        x += 0x9E3779B9
        z = x;  z = (z ^ (z >> 16)) * 0x85EBCA6B;  z = (z ^ (z >> 13)) * 0xC2B2AE35
        s[i] = z ^ (z >> 16)

fmix32 is a bijection and the four Weyl values differ, so at most one s[i] is zero and the
state is never all-zero (the one forbidden xoshiro state).

Uniform in (0, 1]:  u = ((x >> 8) + 1) * 2^-24  - 24 bits, so the value is exact in float and
double alike (the float and double builds draw the same uniforms); never 0, so log(u) is finite.

Gaussian pair by Box-Muller (the basic form, no rejection, one pair per two uniforms):

    u1 = uniform(); u2 = uniform()
    r  = sqrt(-2 * log(u1))
    z0 = r * cos(TWO_PI * u2);  z1 = r * sin(TWO_PI * u2)

with TWO_PI the double (or float) nearest 2*pi. |z| <= sqrt(2*24*ln 2) = 5.77 (the 24-bit
uniform's floor); both values are used, in that order.
"""
from __future__ import annotations

import math

M32 = 0xFFFFFFFF
TWO_PI = 2.0 * math.pi          # 6.283185307179586, the double nearest 2*pi
U24 = 1.0 / 16777216.0          # 2^-24


def _rotl(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & M32


def seed_state(seed: int) -> list[int]:
    """The four uint32 words xoshiro128** starts from for a uint32 seed."""
    x = seed & M32
    s = []
    for _ in range(4):
        x = (x + 0x9E3779B9) & M32
        z = x
        z = ((z ^ (z >> 16)) * 0x85EBCA6B) & M32
        z = ((z ^ (z >> 13)) * 0xC2B2AE35) & M32
        s.append(z ^ (z >> 16))
    return s


class Xoshiro128ss:
    """xoshiro128** with the C twin's seeding, uniform and Box-Muller conversions."""

    def __init__(self, seed: int = 1):
        self.s = seed_state(seed)

    def next_u32(self) -> int:
        s0, s1, s2, s3 = self.s
        result = (_rotl((s1 * 5) & M32, 7) * 9) & M32
        t = (s1 << 9) & M32
        s2 ^= s0
        s3 ^= s1
        s1 ^= s2
        s0 ^= s3
        s2 ^= t
        s3 = _rotl(s3, 11)
        self.s = [s0, s1, s2, s3]
        return result

    def uniform(self) -> float:
        """Uniform in (0, 1] with 24-bit resolution (exact in float and double)."""
        return ((self.next_u32() >> 8) + 1) * U24

    def gauss_pair(self) -> tuple[float, float]:
        """Two independent standard normal samples (Box-Muller)."""
        u1 = self.uniform()
        u2 = self.uniform()
        r = math.sqrt(-2.0 * math.log(u1))
        a = TWO_PI * u2
        return r * math.cos(a), r * math.sin(a)

    def gauss4(self) -> tuple[float, float, float, float]:
        """Four standard normal samples (two Box-Muller pairs), as one particle's noise."""
        a, b = self.gauss_pair()
        c, d = self.gauss_pair()
        return a, b, c, d

    def u32_block(self, n: int) -> list[int]:
        return [self.next_u32() for _ in range(n)]

    def normals(self, n_pairs: int) -> list[float]:
        """2*n_pairs normals, the same as n_pairs calls of gauss_pair() (inlined for speed)."""
        s0, s1, s2, s3 = self.s
        out = []
        log, sqrt, cos, sin = math.log, math.sqrt, math.cos, math.sin
        for _ in range(n_pairs):
            u = []
            for _ in range(2):
                x = (s1 * 5) & M32
                r = ((((x << 7) | (x >> 25)) & M32) * 9) & M32
                t = (s1 << 9) & M32
                s2 ^= s0
                s3 ^= s1
                s1 ^= s2
                s0 ^= s3
                s2 ^= t
                s3 = ((s3 << 11) | (s3 >> 21)) & M32
                u.append(((r >> 8) + 1) * U24)
            rad = sqrt(-2.0 * log(u[0]))
            a = TWO_PI * u[1]
            out.append(rad * cos(a))
            out.append(rad * sin(a))
        self.s = [s0, s1, s2, s3]
        return out
