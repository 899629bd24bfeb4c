"""The one-way data flow, checked on the import graph (AST of every module under twin/)."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "twin"

# layer -> packages/modules it must not import. The runner orchestrates every layer (plan -> measure -> identify ->
# diagnose -> compensate -> evaluate); nothing in a layer imports it, the commands, or a study.
ABOVE = ("twin.runner", "twin.commands", "studies", "experiments")
# The importers (vendor files -> the dataset seam) sit at the edge beside the foundation: they write datasets, and
# nothing behind the seam reads a vendor format.
IMPORTERS = "twin.importers"
FORBIDDEN = {
    "foundation": ("twin.world", "twin.instrument", "twin.estimator", "twin.diagnosis", "twin.evaluation", IMPORTERS, "mujoco", "rerun", "cv2") + ABOVE,
    "importers": ("twin.world", "twin.instrument", "twin.estimator", "twin.diagnosis", "twin.evaluation", "mujoco", "rerun", "cv2") + ABOVE,
    "world": ("twin.instrument", "twin.estimator", "twin.diagnosis", "twin.evaluation", IMPORTERS, "rerun") + ABOVE,
    "instrument": ("twin.world", "twin.estimator", "twin.diagnosis", "twin.evaluation", IMPORTERS, "mujoco", "rerun") + ABOVE,
    "estimator": ("twin.world", "twin.instrument", "twin.diagnosis", "twin.evaluation", IMPORTERS, "mujoco", "rerun", "cv2") + ABOVE,
    "diagnosis": ("twin.world", "twin.instrument", "twin.evaluation", IMPORTERS, "mujoco", "rerun", "cv2") + ABOVE,
    "evaluation": (IMPORTERS, "mujoco") + ABOVE,
    # the runner works on datasets: it imports every layer but the importers (files people have) and the commands
    "runner": (IMPORTERS, "twin.commands", "studies", "experiments", "mujoco", "rerun"),
    "commands": ("studies", "experiments", "mujoco", "rerun"),
}
FOUNDATION = {"transforms", "robot_model", "kinematics", "robots", "camera", "dataset_types", "dataset", "benchio", "presets",
              "cli", "__init__", "urdf", "resources", "runtime", "units", "files"}
# The pure solver is fine anywhere (like scipy.optimize); models, data and rendering are world-only.
ALLOWED = {"mujoco.minimize"}
RERUN_MODULE = "twin/evaluation/recording.py"
# The diagnosis' modules from the bottom up: each imports only modules before it in this order (the package's
# __init__, its public face, sits above them all and no module imports it). docs/architecture.md states the same.
DIAGNOSIS_ORDER = (
    "features", "candidates", "field", "atoms", "values",  # the vocabulary: feature kinds, rows, atoms, their values
    "extend", "floor", "blocks",  # the extended model, the noise floor and sessions, the held-out blocks
    "structure", "configurations", "grams", "problem", "scoring", "ordering", "confirm", "harmonics", "refine",  # the selection's steps
    "loads", "pools", "changes",  # the load terms, the two pools, the change scan
    "describe", "late", "pairs", "rule", "verdict", "after", "diagnose", "effect_fit",  # the procedure; a given model
    # fitted without it
    "apply", "report",  # using an extended calibration; diagnosis.json and the plots
)
DIAGNOSIS_MAX_LINES = 1000


def _layer(path: Path) -> str | None:
    rel = path.relative_to(ROOT)
    if len(rel.parts) == 1:
        return "foundation" if rel.stem in FOUNDATION else None
    return rel.parts[0] if rel.parts[0] in FORBIDDEN else None


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    pkg = "twin." + ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.rstrip(".").split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            # 'from mujoco import minimize' is the module mujoco.minimize, not mujoco itself
            out += [f"{mod}.{a.name}" for a in node.names]
    return out


def _violations():
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        layer = _layer(path)
        for mod in _imports(path):
            if mod.startswith("rerun") and str(path.relative_to(ROOT.parent)) != RERUN_MODULE:
                bad.append(f"{path.relative_to(ROOT.parent)} imports {mod} (only {RERUN_MODULE} may)")
            if layer is None:
                continue
            for f in FORBIDDEN[layer]:
                if (mod == f or mod.startswith(f + ".")) and not any(mod == a or mod.startswith(a + ".") for a in ALLOWED):
                    bad.append(f"{path.relative_to(ROOT.parent)} ({layer}) imports {mod}")
    return bad


def test_layers_import_only_upstream():
    """No layer imports a downstream layer or the world; only the world touches MuJoCo models."""
    assert _violations() == []


def _private_imports():
    """``from module import _name`` of another module, in every module of ``twin/``."""
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        bad.append(f"{path.relative_to(ROOT.parent)} imports {node.module}.{a.name}")
    return bad


def test_no_module_imports_private_names():
    """No module of twin/ (foundation, importers, world, instrument, estimator, diagnosis, evaluation, runner,
    commands) imports another module's private (_name) names."""
    assert _private_imports() == []


def _module_names() -> dict[str, Path]:
    """Every module of twin/ by dotted name (a package by its own name: its __init__)."""
    out = {}
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _import_nodes(tree: ast.AST, *, in_functions: bool):
    """The import statements of a module: those that run when it is imported (at module level, in classes, under
    if/try; ``in_functions=False``) or those inside functions (``in_functions=True``)."""
    out = []

    def visit(node, inside):
        for child in ast.iter_child_nodes(node):
            now = inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, (ast.Import, ast.ImportFrom)) and now == in_functions:
                out.append(child)
            visit(child, now)

    visit(tree, False)
    return out


def _targets(node, me: str, is_package: bool, modules) -> list[str]:
    """The modules of twin an import statement in module ``me`` names: ``from X import a`` is the module ``X.a``
    when there is one, else ``X``."""
    if isinstance(node, ast.Import):
        names = [a.name for a in node.names]
    else:
        base = me if is_package else me.rpartition(".")[0]
        if node.level:
            up = base.split(".")
            mod = ".".join(up[: len(up) - (node.level - 1)] + ([node.module] if node.module else []))
        else:
            mod = node.module or ""
        names = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
    out = []
    for name in names:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        if name:
            out.append(name)
    return out


def _import_graph() -> dict[str, set[str]]:
    """Module -> the modules of twin/ importing it runs (module-level imports only).

    A package counts as its ``__init__``. Importing ``twin.a.b`` runs ``twin.a``'s ``__init__`` first, so from a
    module outside ``twin.a`` it is an import of ``twin.a`` and of ``twin.a.b``; from a module inside ``twin.a`` it
    is an import of ``twin.a.b`` alone (the package is being imported already), and an import of ``twin.a`` itself
    (``from twin.a import name``, ``from . import name`` of a name its ``__init__`` defines) is an import of its
    ``__init__``, which imports its modules: a cycle when they import it."""
    modules = _module_names()
    graph = {}
    for me, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        deps = set()
        for node in _import_nodes(tree, in_functions=False):
            for target in _targets(node, me, path.name == "__init__.py", modules):
                deps.add(target)
                parts = target.split(".")
                for i in range(1, len(parts)):
                    pkg = ".".join(parts[:i])
                    if pkg in modules and not (me == pkg or me.startswith(pkg + ".")):
                        deps.add(pkg)
        deps.discard(me)
        graph[me] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles: the strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_among_the_modules_of_twin():
    """The module-level imports of twin/ form no cycle (a package counts as its __init__: :func:`_import_graph`),
    so that no import needs to hide inside a function."""
    assert _cycles(_import_graph()) == []


def _twin_imports_in_functions(package: str = "diagnosis") -> list[str]:
    """Imports of a module of twin (relative, or ``twin.``) inside a function, in the modules of ``package``."""
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in _import_nodes(ast.parse(path.read_text(), filename=str(path)), in_functions=True):
            if isinstance(node, ast.ImportFrom) and (node.level or (node.module or "").startswith("twin")) or \
                    isinstance(node, ast.Import) and any(a.name.startswith("twin") for a in node.names):
                bad.append(f"{path.relative_to(ROOT.parent)}:{node.lineno}")
    return bad


def test_no_diagnosis_module_imports_twin_inside_a_function():
    """The diagnosis' modules import each other (and the rest of twin) at module level only: a relative import inside
    a function is how a cycle hides."""
    assert _twin_imports_in_functions("diagnosis") == []


def _long_modules(package: str = "diagnosis", most: int = DIAGNOSIS_MAX_LINES) -> list[str]:
    return [f"{p.relative_to(ROOT.parent)}: {n} lines" for p in sorted((ROOT / package).glob("*.py"))
            if (n := len(p.read_text().splitlines())) > most]


def test_no_diagnosis_module_is_over_1000_lines():
    """Every module of twin/diagnosis holds one job in at most 1,000 lines."""
    assert _long_modules() == []


def _diagnosis_order_violations(order=DIAGNOSIS_ORDER) -> list[str]:
    """Imports of a diagnosis module by a module not above it in ``order``, imports of the package's __init__ by its
    modules, and modules missing from (or listed in) ``order`` that are not (or are) in twin/diagnosis."""
    pkg = ROOT / "diagnosis"
    modules = _module_names()
    have = {p.stem for p in pkg.glob("*.py")} - {"__init__"}
    bad = [f"twin/diagnosis/{m}.py is not in the declared order" for m in sorted(have - set(order))]
    bad += [f"{m} is in the declared order but not in twin/diagnosis" for m in order if m not in have]
    rank = {m: i for i, m in enumerate(order)}
    for m in sorted(have & set(order)):
        path = pkg / f"{m}.py"
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in _import_nodes(tree, in_functions=False) + _import_nodes(tree, in_functions=True):
            for target in _targets(node, f"twin.diagnosis.{m}", False, modules):
                if target == "twin.diagnosis":
                    bad.append(f"twin/diagnosis/{m}.py imports the package twin.diagnosis (its __init__)")
                elif target.startswith("twin.diagnosis."):
                    dep = target.split(".")[2]
                    if dep in rank and rank[dep] >= rank[m]:
                        bad.append(f"twin/diagnosis/{m}.py imports {dep}, which is not below it")
    return bad


def test_diagnosis_modules_import_only_modules_below_them():
    """Each module of twin/diagnosis imports only the modules before it in DIAGNOSIS_ORDER (the order
    docs/architecture.md states), and every module of the package is placed in that order."""
    assert _diagnosis_order_violations() == []


DOC = ROOT.parent / "docs" / "architecture.md"


def _documented_diagnosis(doc: str) -> tuple[list[str], dict[str, set[str]]]:
    """docs/architecture.md's diagnosis modules in the order of its table, and its "who may import whom" block."""
    part = doc[doc.index("The diagnosis (`twin.diagnosis`"):]
    table = part[: part.index("Who may import whom")]
    order = re.findall(r"^\| `(\w+)` \|", table, flags=re.M)
    block = part[part.index("Who may import whom"):]
    block = block[block.index("```\n") + 4:]
    block = block[: block.index("\n```")]
    deps: dict[str, set[str]] = {}
    names: list[str] = []
    for line in block.splitlines():
        if not line.startswith(" "):
            head, _, line = line.strip().partition("  ")
            names = [m.strip() for m in head.split(",")]
            for m in names:
                deps[m] = set()
        got = {d.strip() for d in line.split(",") if d.strip() and d.strip() != "none"}
        for m in names:
            deps[m] |= got
    return order, deps


def _diagnosis_imports() -> dict[str, set[str]]:
    """The diagnosis modules each module of twin/diagnosis imports."""
    modules = _module_names()
    out = {}
    for path in sorted((ROOT / "diagnosis").glob("*.py")):
        if path.stem == "__init__":
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        out[path.stem] = {t.split(".")[2] for node in _import_nodes(tree, in_functions=False)
                          for t in _targets(node, f"twin.diagnosis.{path.stem}", False, modules)
                          if t.startswith("twin.diagnosis.")}
    return out


def test_the_architecture_doc_states_the_diagnosis_order_and_imports():
    """docs/architecture.md's diagnosis table lists the modules in DIAGNOSIS_ORDER, and its "who may import whom"
    block is each module's imports."""
    order, deps = _documented_diagnosis(DOC.read_text())
    assert tuple(order) == DIAGNOSIS_ORDER
    assert deps == _diagnosis_imports()


def test_checker_catches_a_forbidden_import(tmp_path, monkeypatch):
    """The checker itself flags an estimator module that imports the world (so the test above can fail)."""
    fake = tmp_path / "twin"
    (fake / "estimator").mkdir(parents=True)
    (fake / "estimator" / "leak.py").write_text("from twin.world import truth\nimport mujoco\n")
    (fake / "estimator" / "ok.py").write_text("from mujoco import minimize\nfrom ..kinematics import pose_jacobian\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    found = _violations()
    assert any("imports twin.world" in v for v in found)
    assert any(v.endswith("imports mujoco") for v in found)
    assert not any("ok.py" in v for v in found)


def test_checker_catches_a_private_import_and_an_upward_import(tmp_path, monkeypatch):
    """The checkers flag ``from .x import _y`` in a public face and an evaluation module importing the runner."""
    fake = tmp_path / "twin"
    (fake / "evaluation").mkdir(parents=True)
    (fake / "evaluation" / "up.py").write_text("from twin.runner import campaign\nfrom .report import _clean\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    assert any("imports twin.runner.campaign" in v for v in _violations())
    assert any("_clean" in v for v in _private_imports())


def test_checker_keeps_the_importers_at_the_edge(tmp_path, monkeypatch):
    """An importer that imports the estimator, and the estimator importing an importer, are both flagged; an
    importer writing through the dataset seam is not."""
    fake = tmp_path / "twin"
    (fake / "importers").mkdir(parents=True)
    (fake / "estimator").mkdir(parents=True)
    (fake / "importers" / "leak.py").write_text("from ..estimator import calibrate\n")
    (fake / "importers" / "ok.py").write_text("from ..dataset import write_dataset\nfrom ..urdf import read_urdf_chain\n")
    (fake / "estimator" / "vendor.py").write_text("from twin.importers.columns import read_column_map\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    found = _violations()
    assert any("leak.py (importers) imports twin.estimator" in v for v in found)
    assert any("vendor.py (estimator) imports twin.importers" in v for v in found)
    assert not any("ok.py" in v for v in found)


def test_checker_catches_a_private_import_in_the_estimator_and_the_diagnosis(tmp_path, monkeypatch):
    """The private-name checker covers every package: the estimator and the diagnosis included."""
    fake = tmp_path / "twin"
    (fake / "estimator").mkdir(parents=True)
    (fake / "diagnosis").mkdir(parents=True)
    (fake / "estimator" / "register.py").write_text("from .core import _stats\n")
    (fake / "diagnosis" / "diagnose.py").write_text("from .describe import _place_unit, describe_terms\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    found = _private_imports()
    assert any("core._stats" in v for v in found) and any("describe._place_unit" in v for v in found)
    assert not any("describe_terms" in v for v in found)


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)


def test_checker_catches_an_import_cycle_and_how_a_package_counts(tmp_path, monkeypatch):
    """A cycle of two modules, and one through a package's __init__ (a module of another package importing back a
    module whose package __init__ imports the first), are found; modules importing their siblings under a package
    __init__ that imports them, and an import inside a function, are not cycles."""
    fake = tmp_path / "twin"
    _write(fake, {
        "__init__.py": "",
        "a/__init__.py": "from .x import f\nfrom .y import g\n",
        "a/x.py": "from .y import g\nfrom twin.a.y import g as h\n",
        "a/y.py": "import numpy as np\n",
        "b/__init__.py": "",
        "b/p.py": "from .q import h\n",
        "b/q.py": "def h():\n    from .p import k\n",
        "c/__init__.py": "from .u import u\n",
        "c/u.py": "from twin.d.v import v\n",
        "c/w.py": "",
        "d/__init__.py": "",
        "d/v.py": "",
    })
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    assert _cycles(_import_graph()) == []
    (fake / "b" / "q.py").write_text("from .p import k\n")
    assert _cycles(_import_graph()) == [["twin.b.p", "twin.b.q"]]
    (fake / "b" / "q.py").write_text("")
    # twin.c.u -> twin.d.v -> twin.c.w: importing twin.c.w runs twin.c's __init__, which imports twin.c.u
    (fake / "d" / "v.py").write_text("from twin.c.w import w\n")
    assert _cycles(_import_graph()) == [["twin.c", "twin.c.u", "twin.d.v"]]


def test_checker_catches_an_import_of_twin_inside_a_diagnosis_function(tmp_path, monkeypatch):
    """A relative (or twin.) import inside a function of a diagnosis module is flagged; a lazy import of a third-party
    module inside a function is not."""
    fake = tmp_path / "twin"
    _write(fake, {"diagnosis/loads.py": "import numpy as np\n\n\ndef f():\n    from .atoms import Atom\n"
                                        "    import matplotlib\n    return Atom, matplotlib\n",
                  "diagnosis/ok.py": "from .atoms import Atom\n\n\ndef g():\n    from scipy.optimize import minimize\n"})
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    assert _twin_imports_in_functions("diagnosis") == ["twin/diagnosis/loads.py:5"]


def test_checker_catches_a_long_diagnosis_module(tmp_path, monkeypatch):
    """A diagnosis module of 1,001 lines is flagged, one of 1,000 is not."""
    fake = tmp_path / "twin"
    _write(fake, {"diagnosis/long.py": "x = 1\n" * 1001, "diagnosis/fine.py": "x = 1\n" * 1000})
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    assert _long_modules() == ["twin/diagnosis/long.py: 1001 lines"]


def test_checker_catches_an_upward_import_in_the_diagnosis(tmp_path, monkeypatch):
    """A diagnosis module importing one above it in the order, one importing the package's __init__, and a module
    the order does not place are all flagged; imports downward are not."""
    fake = tmp_path / "twin"
    _write(fake, {"diagnosis/__init__.py": "from .rule import x\n",
                  "diagnosis/atoms.py": "from .features import Pow\n",
                  "diagnosis/features.py": "",
                  "diagnosis/rule.py": "from .atoms import Atom\nfrom twin.diagnosis.features import Pow\n",
                  "diagnosis/scoring.py": "from .rule import select_terms\nfrom twin.diagnosis import atoms\n"
                                          "from twin.diagnosis import Atom\n",
                  "diagnosis/extra.py": ""})
    monkeypatch.setattr(__import__(__name__), "ROOT", fake)
    found = _diagnosis_order_violations(("features", "atoms", "scoring", "rule"))
    assert found == ["twin/diagnosis/extra.py is not in the declared order",
                     "twin/diagnosis/scoring.py imports rule, which is not below it",
                     "twin/diagnosis/scoring.py imports the package twin.diagnosis (its __init__)"]
