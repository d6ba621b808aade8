"""The library's layers import only the layers above them, in the order data flows (docs/layout.md).

common -> methods -> measures -> agents -> ood -> scoring -> reporting -> pipeline -> experiments,
then guard, study and bench, which may use everything. A module may import its own layer.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PAPER_LIB = Path(__file__).resolve().parents[2] / "paper_lib"
LAYERS = ("common", "methods", "measures", "agents", "ood", "scoring", "reporting", "pipeline", "experiments",
          "guard", "study", "bench", "deploy")
#: Imports that cross the order today, each with why; the list may only shrink.
KNOWN_CROSSINGS: dict[tuple[str, str], str] = {}


def layer_of(module: str) -> int | None:
    """The layer index of a dotted paper_lib module (None for the package root and its data)."""
    parts = module.split(".")
    if len(parts) < 2 or parts[1] not in LAYERS:
        return None
    rank = LAYERS.index(parts[1])
    return min(rank, LAYERS.index("guard")) if parts[1] in ("guard", "study", "bench", "deploy") else rank


def imports(path: Path) -> list[tuple[str, int, bool]]:
    """(imported paper_lib module, line, at module top) for every import in a file."""
    tree = ast.parse(path.read_text())
    top = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("paper_lib"):
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names if a.name.startswith("paper_lib")]
        for name in names:
            found.append((name, node.lineno, id(node) in top))
    return found


def module_name(path: Path) -> str:
    rel = path.relative_to(PAPER_LIB.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def crossings() -> dict[tuple[str, str], str]:
    """Every import from a module to a later layer: {(importer, imported): 'file:line'}."""
    found = {}
    for path in sorted(PAPER_LIB.rglob("*.py")):
        importer = module_name(path)
        here = layer_of(importer)
        if here is None:
            continue  # paper_lib/__init__.py is the public face: it may gather names from every layer
        for imported, line, _ in imports(path):
            there = layer_of(imported)
            if there is not None and there > here:
                target = ".".join(imported.split(".")[:3])
                found.setdefault((importer, target), f"{path.relative_to(PAPER_LIB.parent)}:{line}")
    return found


def test_every_module_lives_in_a_layer():
    flat = [p.name for p in PAPER_LIB.glob("*.py") if p.name != "__init__.py"]
    assert flat == [], f"modules directly in paper_lib/: {flat}; put each in its layer's package (docs/layout.md)"
    packages = sorted(p.name for p in PAPER_LIB.iterdir() if (p / "__init__.py").is_file())
    assert set(packages) - {"data"} == set(LAYERS), packages


def test_layers_import_only_the_layers_above_them():
    found = crossings()
    new = {k: v for k, v in found.items() if k not in KNOWN_CROSSINGS}
    assert not new, "imports against the layer order (docs/layout.md): " + "; ".join(
        f"{a} imports {b} ({where})" for (a, b), where in sorted(new.items()))
    stale = sorted(set(KNOWN_CROSSINGS) - set(found))
    assert not stale, f"KNOWN_CROSSINGS lists crossings that are gone; delete them: {stale}"


def test_the_check_sees_a_crossing(tmp_path):
    """The import walk finds a lazy import inside a function, not only those at the top."""
    module = tmp_path / "m.py"
    module.write_text("def f():\n    from paper_lib.pipeline.config import load_run_config\n")
    assert imports(module) == [("paper_lib.pipeline.config", 2, False),
                               ("paper_lib.pipeline.config.load_run_config", 2, False)]
    assert layer_of("paper_lib.pipeline.config") > layer_of("paper_lib.scoring.metrics")


def resolve(name: str) -> str | None:
    """The paper_lib module a dotted import name refers to (`paper_lib.a.b.func` -> `paper_lib.a.b`)."""
    parts = name.split(".")
    while parts:
        base = PAPER_LIB.parent.joinpath(*parts)
        if base.with_suffix(".py").is_file() or (base / "__init__.py").is_file():
            return ".".join(parts)
        parts.pop()
    return None


def module_file(module: str) -> Path:
    base = PAPER_LIB.parent.joinpath(*module.split("."))
    return base / "__init__.py" if base.is_dir() else base.with_suffix(".py")


def closure(roots: set[str]) -> set[str]:
    """Every paper_lib module the given modules import, directly or not, at the top or inside functions.

    A package's __init__ runs before any of its modules, so it counts too.
    """
    seen, todo = set(), set(roots)
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        seen.add(module)
        parents = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 1)}
        todo |= parents - seen
        for name, _, at_top in imports(module_file(module)):
            if module == "paper_lib" and not at_top:
                continue  # the root's lazy `__getattr__` serves the guard's names only when asked for
            target = resolve(name)
            if target and target not in seen:
                todo.add(target)
    return seen


def notebook_imports(path: Path) -> set[str]:
    """The paper_lib modules a notebook's code cells import."""
    import json

    found = set()
    for cell in json.loads(path.read_text())["cells"]:
        if cell["cell_type"] != "code":
            continue
        source = "".join(cell["source"])
        try:
            tree = ast.parse(source)
        except SyntaxError:  # IPython magics
            tree = ast.parse("\n".join(line for line in source.splitlines() if not line.lstrip().startswith(("%", "!"))))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("paper_lib"):
                found |= {resolve(f"{node.module}.{a.name}") for a in node.names}
            elif isinstance(node, ast.Import):
                found |= {resolve(a.name) for a in node.names if a.name.startswith("paper_lib")}
    return found - {None}


#: Stages that train: their code deps stay narrow on purpose. A folder dep would make every edit of the
#: library a retrain of days under `make retrain`; the training code is held still by the frozen-numerics
#: test (tests/methods/test_training_numerics.py) instead.
TRAINING_STAGES = ("train", "study_sweep", "scaling_train", "ensembles_train")


def stage_code(cmd: str) -> set[str]:
    """The paper_lib modules a dvc.yaml command runs: `python -m` modules and the notebooks' imports."""
    import re

    roots = set(re.findall(r"-m (paper_lib[\w.]*)", cmd))
    for notebook in re.findall(r"(?<![\w/])(notebooks/\w+\.ipynb)", cmd):
        roots |= notebook_imports(PAPER_LIB.parent / notebook)
    return roots


def needed_deps(cmd: str) -> set[str]:
    """The code folders (layer packages) a stage's outputs depend on, with the root module and the data."""
    packages = {module.split(".")[1] for module in closure(stage_code(cmd)) if module.count(".") >= 1}
    deps = {f"paper_lib/{package}" for package in packages} | {"paper_lib/__init__.py"}
    return deps | ({"paper_lib/data"} if "agents" in packages else set())


def test_dvc_stages_depend_on_all_the_code_they_run():
    """No code change can leave an output marked up to date: every stage lists the packages it imports."""
    import yaml

    stages = yaml.safe_load((PAPER_LIB.parent / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        if name in TRAINING_STAGES:
            continue
        stage = stage.get("do", stage)  # per-run stages: `foreach` over runs.yaml, the stage under `do`
        listed = {dep for dep in stage.get("deps", []) if isinstance(dep, str)}
        missing = needed_deps(stage["cmd"]) - listed
        assert not missing, f"dvc.yaml stage {name!r} runs code in {sorted(missing)} but does not list it under deps"


def test_the_package_root_exports_about_a_dozen_names_and_loads_the_heavy_ones_on_first_use():
    """`from paper_lib import ...` serves what a user of the methods needs; the rest lives in its layer's package.

    Nothing is imported before it is asked for: the notebook runner (every notebook stage) needs neither torch nor
    jsonschema's Lark grammars, which took about 5 s of each stage.
    """
    probe = ("import sys, paper_lib.pipeline.notebook_run; heavy = ('torch', 'stable_baselines3', 'lark', 'sklearn', "
             "'paper_lib.guard', 'paper_lib.pipeline.evaluate_agent'); "
             "print([m for m in heavy if m in sys.modules]); "
             "print([n for n in paper_lib.__all__ if getattr(paper_lib, n, None) is None]); "
             "print(paper_lib.Guard.__module__, paper_lib.evaluate_agent.__module__)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    loaded_at_import, unresolved, lazy_homes = done.stdout.splitlines()
    assert loaded_at_import == "[]" and unresolved == "[]", done.stdout
    assert lazy_homes == "paper_lib.guard.core paper_lib.pipeline.evaluate_agent", done.stdout
    import paper_lib

    assert 10 <= len(paper_lib.__all__) <= 16, paper_lib.__all__
