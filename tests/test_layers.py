"""The package's layers import only downward (DESIGN.md, "The house").

Every import in src/ahrsgen, at module level or inside a function, is read with `ast` and its
target's layer compared with the importer's: a module may import its own layer or any below,
never one above, and nothing of the checkout outside src/ahrsgen (tests, studies, docs,
examples). The layers, bottom first, are listed once here and in ahrsgen/__init__.py's
docstring.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PKG = SRC / "ahrsgen"

# Bottom first. A module belongs to the first entry that is its name or a prefix of it.
LAYERS = [
    ["ahrsgen.errors", "ahrsgen.argtypes", "ahrsgen.constants", "ahrsgen.status", "ahrsgen.npquat",
     "ahrsgen.paths", "ahrsgen.fileio", "ahrsgen.sensor_frame", "ahrsgen"],
    ["ahrsgen.symbolic"],
    ["ahrsgen.codegen"],
    ["ahrsgen.filters", "ahrsgen.scaffold"],
    ["ahrsgen.generate"],
    ["ahrsgen.sim"],
    ["ahrsgen.target", "ahrsgen.bench", "ahrsgen.calibrate"],
    ["ahrsgen.check", "ahrsgen.tune"],
    ["ahrsgen.cli", "ahrsgen.__main__"],
]
OUTSIDE = ("tests", "studies", "docs", "examples", "generator", "firmware_sim")


def layer_of(module: str) -> int:
    best, best_len = None, -1
    for i, names in enumerate(LAYERS):
        for n in names:
            if (module == n or module.startswith(n + ".")) and len(n) > best_len:
                best, best_len = i, len(n)
    assert best is not None, f"{module} is in no layer: add it to LAYERS"
    return best


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) for every import in the file; relative imports resolved."""
    mod = module_name(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "ahrsgen" or (node.level and not node.module):
                # `from ahrsgen import x` imports the module ahrsgen.x
                out += [(node.lineno, f"{target}.{a.name}") for a in node.names]
            else:
                out.append((node.lineno, target))
    return out


def violations(files) -> list[str]:
    bad = []
    for path in files:
        mod = module_name(path)
        here = layer_of(mod)
        for line, target in imports_of(path):
            top = target.split(".")[0]
            if top in OUTSIDE:
                bad.append(f"{path.relative_to(SRC)}:{line} imports {target}, outside the package")
            elif top == "ahrsgen" and layer_of(target) > here:
                bad.append(f"{path.relative_to(SRC)}:{line} ({mod}, layer {here}) imports {target} "
                           f"(layer {layer_of(target)}): an import up the layers")
    return bad


def package_files():
    return sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def test_every_import_runs_down_the_layers():
    assert violations(package_files()) == []


def test_every_module_has_a_layer():
    for p in package_files():
        layer_of(module_name(p))


@pytest.mark.parametrize("line, words", [
    ("from ahrsgen.cli import main\n", "import up the layers"),                 # symbolic -> cli
    ("from ahrsgen import tune\n", "import up the layers"),
    ("import firmware_sim.host\n", "outside the package"),
])
def test_the_check_sees_an_import_up(tmp_path, monkeypatch, line, words):
    """The check itself: a module of the symbolic layer importing the CLI is reported."""
    fake = PKG / "symbolic" / "_layer_probe.py"
    src = tmp_path / "probe.py"
    src.write_text(line)
    monkeypatch.setattr(Path, "read_text", lambda self, *a, **k: line if self == fake else Path.read_bytes(self).decode())
    found = violations([fake])
    assert found and words in found[0], found


def test_the_tests_mirror_the_package():
    """tests/README.md: a test of src/ahrsgen/X/ lives in tests/X/, one of a top-level module
    src/ahrsgen/x.py is tests/test_x.py (or a house test). So every folder of tests/ that holds
    tests names a package folder of src/ahrsgen, and every top-level test file names a top-level
    module or is one of the house's."""
    tests = Path(__file__).resolve().parent
    house = {"test_layers.py", "test_ci_honesty.py", "test_wheel.py", "test_docs_tables.py"}
    for f in tests.rglob("test_*.py"):
        rel = f.relative_to(tests)
        if len(rel.parts) == 1:
            assert rel.name in house or (PKG / rel.name.removeprefix("test_")).is_file(), \
                f"tests/{rel}: no src/ahrsgen/{rel.name.removeprefix('test_')}; put it beside what it tests"
        else:
            assert (PKG / rel.parent).is_dir(), f"tests/{rel}: no folder src/ahrsgen/{rel.parent}"
