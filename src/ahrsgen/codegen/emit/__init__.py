"""CasADi SX Function -> kernel objects printed as straight-line C, for float or double.

The emitter walks the SX function's instruction list (Function.instruction_id/_input/
_output/_constant) and writes one named `const` temporary per operation, so the C reads
like the equations and shares every common subexpression once. It knows nothing about
attitude: it turns any SX function whose inputs and outputs are dense into

    static void <name>(const float a[3], float b, ..., float out[4], float *scalar_out)

Rules (DESIGN.md): float builds use the f-suffixed <math.h> functions and literals so no
double is ever computed; min/max/comparisons become conditional expressions (no libm call,
NaN-safe on every target, identical on host and target); inputs and constants are inlined;
outputs are written after every temporary is computed, so an output may alias an input.
Matrices are passed flattened in CasADi's column-major order. Each kernel reports its
operation counts. With math="fast" a float kernel calls src/ahrsgen/codegen/fastmath.py's helpers
(no libm) instead of sinf/cosf/atan2f/asinf/acosf/atanf, and lists the helpers it uses.
A constant the caller names (emit's `names`: a folded parameter, src/ahrsgen/codegen/folded.py) is
written with its name in a comment beside it, the C otherwise unchanged.

Modules: ir (the kernel as data: expression trees, statements, parameters, and the one
printer that writes C; every reader of a kernel reads these, none parses C), ops (the
expression and cost category of each operation, literals), kernel (the walk over the
instructions: emit, Kernel with its Args/Outputs comment), rewrite (exact reciprocals, fused
multiply-adds), branches (selects as if/else), split (long kernels as parts), names (names of
derived literals), build (function, runtime_symbol).
"""
from __future__ import annotations

from ahrsgen.codegen.emit.build import RUNTIME_PREFIX, function, runtime_symbol
from ahrsgen.codegen.emit.kernel import BRANCH_MIN_COST, INLINE_TEMPS, SPLIT_TEMPS, Arg, Kernel, emit
from ahrsgen.codegen.emit.ops import CATEGORIES, PRECISIONS, SUPPORTED, EmitError, literal, op_name

__all__ = ["BRANCH_MIN_COST", "CATEGORIES", "INLINE_TEMPS", "PRECISIONS", "RUNTIME_PREFIX", "SPLIT_TEMPS",
           "SUPPORTED", "Arg", "EmitError", "Kernel", "emit", "function", "literal", "op_name", "runtime_symbol"]
