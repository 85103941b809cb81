"""Shared fixtures: scenarios and host builds are made once per session.

Tools: a test that needs something `.ci/setup` installs says so with `needs(...)` (a skipif
marker) or `require(...)` (inside the test). Without the tool it is skipped with a reason that
starts with MISSING_TOOL; under CI=true such a skip, and an importorskip of one of the Python
packages setup installs, is turned into a failure by the hook below: CI runs every check it
claims, or goes red. Data files that are absent (../shared) may still skip.
"""
from __future__ import annotations

import functools
import importlib.util
import os
import shutil
from pathlib import Path

import pytest

# The repository and this folder, for tests in any sub-folder.
REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"

CI = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")
MISSING_TOOL = "missing tool that .ci/setup installs"

# Python packages of the [dev] extra that tests or the code under test import.
CI_MODULES = ("ahrs", "vqf", "imufusion", "pyulog", "matplotlib", "unicorn", "elftools")


def _have(name: str) -> bool:
    if name in CI_MODULES:
        return importlib.util.find_spec(name) is not None
    if name == "pyelftools":
        return importlib.util.find_spec("elftools") is not None
    if name == "clang-fuzzer":          # clang whose -fsanitize=fuzzer,address,undefined links
        from ahrsgen.check import harden
        return harden.clang_fuzzer_works()
    if name == "cppcheck":
        from ahrsgen.check import static, tools
        return tools.have_tool(static.CPPCHECK)
    if name == "target":                # arm-none-eabi-gcc + newlib, qemu-system-arm, unicorn, pyelftools
        from ahrsgen import target
        return not target.missing_tools()
    return shutil.which(name) is not None     # an executable: cc, arm-none-eabi-gcc, qemu-system-arm


@functools.cache
def missing(*names: str) -> tuple[str, ...]:
    return tuple(n for n in names if not _have(n))


def needs(*names: str) -> pytest.MarkDecorator:
    """Skip marker for tests that need these tools (fails instead under CI=true)."""
    m = missing(*names)
    return pytest.mark.skipif(bool(m), reason=f"{MISSING_TOOL}: {', '.join(m)}")


def require(*names: str) -> None:
    """Inside a test: skip (fail under CI=true) unless these tools are present."""
    m = missing(*names)
    if m:
        pytest.skip(f"{MISSING_TOOL}: {', '.join(m)}")


def _is_tool_skip(reason: str) -> bool:
    return MISSING_TOOL in reason or any(f"could not import '{mod}'" in reason for mod in CI_MODULES)


def _fail_tool_skip(rep) -> None:
    if not (CI and rep.skipped) or hasattr(rep, "wasxfail"):
        return
    reason = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
    if _is_tool_skip(reason):
        rep.outcome = "failed"
        rep.longrepr = f"CI=true and this check did not run: {reason}"


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    """A whole module skipped at import (a module-level importorskip) counts too."""
    outcome = yield
    _fail_tool_skip(outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_tool_skip(outcome.get_result())


@functools.cache
def scenario(name: str, seed: int = 0, **opts):
    from ahrsgen.sim import scenarios
    return scenarios.make(name, seed=seed, **opts)


@functools.cache
def host_build(filter_name: str, precision: str = "float", sets: tuple = ()):
    from ahrsgen.generate import config
    from ahrsgen.sim import host
    return host.build(config.resolve(filter_name, sets=list(sets), precision=precision))


@functools.cache
def reference_run(filter_name: str, scenario_name: str, sets: tuple = (), seed: int = 0, **opts):
    from ahrsgen.generate import config
    from ahrsgen.sim import host
    cfg = config.resolve(filter_name, sets=list(sets))
    return host.run_reference(cfg.spec.reference(cfg.params), scenario(scenario_name, seed, **opts))


@pytest.fixture(scope="session")
def fixedwing():
    return scenario("fixedwing_gps")


def cli_run(argv, capsys):
    """`ahrsgen ARGV` in this process: (exit status, stdout, stderr)."""
    from ahrsgen import cli
    try:
        rc = cli.main(argv)
    except SystemExit as e:          # argparse
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture
def no_build(monkeypatch):
    """Fails the test if anything is compiled: bad input must be refused before any build."""
    from ahrsgen.sim import host

    def refuse(*a, **k):
        raise AssertionError("compiled before the bad input or output path was refused")
    monkeypatch.setattr(host, "build", refuse)


# Runtime builds that the tests of generated kernels cover besides the default ones (the
# parameters of tests/generate/test_runtime_params.py's cases).
RUNTIME_BUILDS = {"qcf": "kp,ki", "mekf": "gyro_noise,accel_angle_noise,gps_min_speed"}


@functools.cache
def rendered(name: str, precision: str = "float", runtime: str = "", math: str | None = None, fma: bool = False):
    """A build of a filter rendered now (ahrsgen.generate.render.Generated: files, manifest,
    kernel objects), shared by the tests that read kernels."""
    from ahrsgen.generate import config, render
    return render.render(config.resolve(name, precision=precision, runtime=runtime or None, math=math, fma=fma))


def kernel_builds() -> list[tuple[str, str, str]]:
    """(filter, precision, runtime) for every filter: float and double, default and runtime."""
    from ahrsgen import filters
    return sorted({(n, p, r) for n in filters.names() for p in ("float", "double")
                   for r in ("", RUNTIME_BUILDS.get(n, ""))})
