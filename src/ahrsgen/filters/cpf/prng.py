"""The CPF's pseudo-random number generator, written with the exact semantics of its C twin.

The generated C (the filter's step partial) and this module produce the same 32-bit integer
stream for the same seed, and in double precision the same uniforms and Gaussian samples bit
for bit (the conversions below are exact, and the ziggurat's rare wedge and tail use libm's exp/log through
Python's `math` module, i.e. the same glibc functions the host C calls).

Generator: xoroshiro64** 1.0 (Blackman & Vigna, 2018; prng.di.unimi.it/xoroshiro64starstar.c),
64-bit state s[0..1] (uint32), period 2^64 - 1, every output bit passes the authors' tests:

    result = rotl(s0 * 0x9E3779BB, 5) * 5   (all mod 2^32)
    s1 ^= s0;  s0 = rotl(s0, 26) ^ s1 ^ (s1 << 9);  s1 = rotl(s1, 13)

(Until issue 14 it was xoshiro128** 1.1, 128-bit state: the same quality of 32-bit output, but
2 to 3 more instructions a draw on the Cortex-M4F and two more registers held through the
particle loop; at 300 draws a step and 1 kHz the period of 2^64 lasts 2 million years.)

Seeding from one uint32 `seed` (SplitMix32-style, MurmurHash3's fmix32 on a Weyl sequence):

    x = seed
    for i in 0..1:
        x += 0x9E3779B9
        z = x;  z = (z ^ (z >> 16)) * 0x85EBCA6B;  z = (z ^ (z >> 13)) * 0xC2B2AE35
        s[i] = z ^ (z >> 16)

fmix32 is a bijection and the two Weyl values differ, so at most one s[i] is zero and the
state is never all-zero (the one forbidden state).

Uniform in (0, 1]:  u = ((x >> 8) + 1) * 2^-24  - 24 bits, so the value is exact in float and
double alike (the float and double builds draw the same uniforms); never 0, so log(u) is finite.

Gaussian by Marsaglia and Tsang's ziggurat (J. Stat. Softw. 5(8), 2000), 128 layers, with
the index, the sign and the magnitude taken from different bits of one 32-bit draw (Doornik's
remedy for the original's correlation):

    u = next_u32();  i = u & 127;  negative = u & 128;  j = u >> 8          (24 bits)
    x = u * (W[i] / 256)
    j < K[i]      -> x                          (about 98.8 % of draws: no libm at all)
    i == 0        -> tail beyond R: repeat xt = -log(uniform()) / R, y = -log(uniform())
                     until y + y >= xt * xt; x = R + xt
    otherwise     -> wedge: F[i] + uniform() * (F[i-1] - F[i]) < exp(-x * x / 2) -> x,
                     else draw again
    result = -x if negative else x

x is the whole draw u = 256 j + (u & 255) scaled by W[i]/256, i.e. j W[i] plus less than one
step W[i] of the 24-bit magnitude (a fixed fraction of a step per layer and sign: the
magnitude's resolution is 2^-24 of the layer either way); the C then needs no shift for the
product, and it tests u < 256 K[i], the same test as j < K[i]. (Until issue 14's last change
x = j W[i].) K, W, F are computed once (ziggurat_tables, Marsaglia and Tsang's zigset with 2^24
in place of 2^31) and written into the C as literals (256 K and W/256, exact), so the double C and this module compute the same
products and comparisons bit for bit (the rare tail and wedge use exp/log: glibc's on both
sides). |z| <= R + 24 ln 2 / R = 8.27 (the 24-bit uniform's floor in the tail).
"""
from __future__ import annotations

import math

from ahrsgen.constants import Const

M32 = 0xFFFFFFFF
U24 = 1.0 / 16777216.0          # 2^-24

ZIG_LAYERS = 128
ZIG_R = Const("ZIG_R", 3.442619855899)          # start of the tail (Marsaglia & Tsang, 128 layers)
ZIG_V = 9.91256303526217e-3     # area of each layer


def ziggurat_tables() -> tuple[list[int], list[float], list[float]]:
    """K (24-bit acceptance thresholds), W (j -> x scale) and F (density at the layer
    edges) of the 128-layer ziggurat, as Marsaglia and Tsang's zigset with m = 2^24."""
    m = 16777216.0
    dn = tn = ZIG_R
    q = ZIG_V / math.exp(-0.5 * dn * dn)
    K, W, F = [0] * ZIG_LAYERS, [0.0] * ZIG_LAYERS, [0.0] * ZIG_LAYERS
    K[0], K[1] = int((dn / q) * m), 0
    W[0], W[-1] = q / m, dn / m
    F[0], F[-1] = 1.0, math.exp(-0.5 * dn * dn)
    for i in range(ZIG_LAYERS - 2, 0, -1):
        dn = math.sqrt(-2.0 * math.log(ZIG_V / dn + math.exp(-0.5 * dn * dn)))
        K[i + 1] = int((dn / tn) * m)
        tn = dn
        F[i] = math.exp(-0.5 * dn * dn)
        W[i] = dn / m
    return K, W, F


ZIG_K, ZIG_W, ZIG_F = ziggurat_tables()


def _rotl(x: int, k: int) -> int:
    return ((x << k) | (x >> (32 - k))) & M32


def seed_state(seed: int) -> list[int]:
    """The two uint32 words xoroshiro64** starts from for a uint32 seed."""
    x = seed & M32
    s = []
    for _ in range(2):
        x = (x + 0x9E3779B9) & M32
        z = x
        z = ((z ^ (z >> 16)) * 0x85EBCA6B) & M32
        z = ((z ^ (z >> 13)) * 0xC2B2AE35) & M32
        s.append(z ^ (z >> 16))
    return s


class Xoroshiro64ss:
    """xoroshiro64** with the C twin's seeding, uniform and ziggurat conversions."""

    def __init__(self, seed: int = 1):
        self.s = seed_state(seed)

    def next_u32(self) -> int:
        s0, s1 = self.s
        result = (_rotl((s0 * 0x9E3779BB) & M32, 5) * 5) & M32
        s1 ^= s0
        s0 = _rotl(s0, 26) ^ s1 ^ ((s1 << 9) & M32)
        s1 = _rotl(s1, 13)
        self.s = [s0, s1]
        return result

    def uniform(self) -> float:
        """Uniform in (0, 1] with 24-bit resolution (exact in float and double)."""
        return ((self.next_u32() >> 8) + 1) * U24

    def gauss(self) -> float:
        """One standard normal sample (the ziggurat above)."""
        K, W, F = ZIG_K, ZIG_W, ZIG_F
        while True:
            u = self.next_u32()
            i = u & 127
            j = u >> 8
            x = u * (W[i] / 256.0)
            if j < K[i]:
                return -x if u & 128 else x
            if i == 0:
                while True:
                    xt = -math.log(self.uniform()) / ZIG_R
                    y = -math.log(self.uniform())
                    if y + y >= xt * xt:
                        break
                x = ZIG_R + xt
                return -x if u & 128 else x
            if F[i] + self.uniform() * (F[i - 1] - F[i]) < math.exp(-0.5 * x * x):
                return -x if u & 128 else x

    def gauss_pair(self) -> tuple[float, float]:
        """Two independent standard normal samples."""
        return self.gauss(), self.gauss()

    def gauss4(self) -> tuple[float, float, float, float]:
        """Four standard normal samples, as one particle's noise."""
        return self.gauss(), self.gauss(), self.gauss(), self.gauss()

    def u32_block(self, n: int) -> list[int]:
        return [self.next_u32() for _ in range(n)]

    def normals(self, n_pairs: int) -> list[float]:
        """2*n_pairs normals, the same as n_pairs calls of gauss_pair()."""
        g = self.gauss
        return [g() for _ in range(2 * n_pairs)]
