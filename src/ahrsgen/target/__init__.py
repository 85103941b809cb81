"""Cortex-M4F target checks: cross build, run in QEMU, compare with the host, footprint.

What a flight-controller engineer asks of generated code: does it give the same answers
on my MCU as on my PC, and how much flash, RAM, stack and time does it take?  This
module answers both with real tools:

* **Cross build** with ``arm-none-eabi-gcc`` for a Cortex-M4F (``-mcpu=cortex-m4 -mthumb
  -mfpu=fpv4-sp-d16 -mfloat-abi=hard``) at ``-O2`` and ``-Os``, linked with the product's
  own startup code and linker script (``src/ahrsgen/target/``) into a bare-metal image.
* **Run** under ``qemu-system-arm -M mps2-an386`` (a Cortex-M4 with FPU).  The image reads
  the sensor log from a host file and writes, for every sample, the status and the raw
  bytes of the state struct back through semihosting; nothing is printed as decimal text,
  so the comparison with the host build is exact to the bit.
* **Footprint** per filter and build: flash (text + rodata + .data image) and static RAM
  (state struct, .data, .bss) as the *increase* over a baseline image that does not call
  the filter, so everything the filter drags in from newlib counts; worst-case stack of
  ``step`` from ``-fstack-usage`` plus the call graph of the linked image (objdump),
  checked against the stack actually touched (stack painting in the image and in
  unicorn); instructions per ``step`` for every step, from QEMU ``-icount`` with SysTick,
  checked step by step against an exact count of the ELF's own code run in the
  ``unicorn`` emulator.  Instructions, not cycles: QEMU does not model the M4 pipeline
  and QEMU 7.2 has no DWT CYCCNT.

Both builds use ``-ffp-contract=off`` (the M4 FPU has VFMA; a fused multiply-add rounds
once and would make the target differ from x86-64 without it) and ``-fno-math-errno``
(``sqrtf`` becomes one ``vsqrt.f32``; without it GCC adds a compare and a call to the
library ``sqrtf`` for the errno case).  Basic arithmetic and ``sqrtf`` are correctly
rounded IEEE-754 on both sides; the transcendental functions (``sinf``, ``atan2f``, ...)
come from newlib on the target and glibc on the host and differ by 1 ulp for some
arguments (``libm_survey``).  So the comparison runs twice: with the real libm against a
stated bound, and with ``target/libm_pinned.h`` (float functions through double, on both
sides), where every filter must be bit-identical in every step.  docs/target.md has the
figures, re-measured by tests/target/test_target.py.

The package: ``build`` (toolchain, flags, harness binding, cross build), ``emulate`` (QEMU
and unicorn runs, libm survey), ``footprint`` (sizes, stack, instruction counts), ``cycles`` (estimated
Cortex-M4 cycles from the TRM's timings), ``check``
(host comparison, verdicts, one filter end to end), ``cli`` (``ahrsgen target``).
"""
from .build import *  # noqa: F401,F403
from .build import _run  # noqa: F401
from .check import *  # noqa: F401,F403
from .check import _COMMON_STATUS_MASK, _print_results  # noqa: F401
from .emulate import *  # noqa: F401,F403
from .footprint import *  # noqa: F401,F403
