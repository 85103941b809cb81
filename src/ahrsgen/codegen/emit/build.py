"""SX Functions for emission, and the symbols of runtime parameters."""
from __future__ import annotations

import casadi as ca


# Symbols named with this prefix stand for parameters read at run time (a runtime build):
# `function` makes the ones an output depends on extra scalar inputs of the kernel.
RUNTIME_PREFIX = "param_"


def runtime_symbol(name: str) -> ca.SX:
    return ca.SX.sym(RUNTIME_PREFIX + name)


def function(name: str, inputs: dict, outputs: dict) -> ca.Function:
    """Build an SX Function for emission from ordered {name: SX} dicts (CSE on, SSA work).

    Runtime-parameter symbols (runtime_symbol) the outputs use become trailing inputs, named
    after the symbol; any other free symbol is an error (CasADi's)."""
    outs = [ca.densify(v) for v in outputs.values()]
    ins, names = list(inputs.values()), list(inputs.keys())
    given = {str(s) for v in ins for s in ca.symvar(v)}
    for s in ca.symvar(ca.veccat(*outs)) if outs else []:
        n = str(s)
        if n.startswith(RUNTIME_PREFIX) and n not in given:
            ins.append(s)
            names.append(n)
            given.add(n)
    return ca.Function(name, ins, outs, names, list(outputs.keys()),
                       {"cse": True, "live_variables": False})
