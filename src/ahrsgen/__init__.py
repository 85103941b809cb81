"""ahrsgen: attitude filters as CasADi equations, emitted as fixed-size C.

Layers, each importing only those below it (tests/test_layers.py):
  errors, argtypes, constants, status, npquat, paths, fileio   plain Python and NumPy
  symbolic      CasADi building blocks
  codegen       the emitter, renderer, templates, filter-model contract, configs
  filters       one folder per filter; scaffold writes a new one
  generate      a configuration resolved and rendered into C (config, render)
  sim           scenarios with truth, log readers, host harness, peers, metrics, fleets
  target, bench, check, tune   the verdicts
  cli           the `ahrsgen` command
"""
from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("ahrsgen")
except _metadata.PackageNotFoundError:      # a source tree on sys.path, not installed
    __version__ = "0+unknown"
