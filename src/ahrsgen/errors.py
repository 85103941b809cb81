"""The error types every layer raises, in one module that imports nothing heavy (no CasADi, no
NumPy), so that a reader of logs or a fleet can name a configuration error without loading
the symbolic stack. The CLI turns each into one line on stderr and exit 2 (or 1 for a failed
check)."""
from __future__ import annotations


class ConfigError(ValueError):
    """A bad configuration: unknown parameter, value out of range, malformed file."""


class LogError(ValueError):
    """A log file that cannot be read: the message names the file and what is wrong (one line)."""


class EmitError(ValueError):
    """A function the emitter cannot turn into C (unsupported operation, sparse input...)."""


class BuildError(RuntimeError):
    """The host C compiler refused a generated source or a harness file."""


class ToolchainMissing(RuntimeError):
    """The cross toolchain, QEMU or the Python emulator packages are not installed."""
