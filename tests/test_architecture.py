"""The one-way data flow, checked on the import graph (AST of every module under twin/)."""

import ast
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
FOUNDATION = {"transforms", "kinematics", "robots", "camera", "dataset", "benchio", "presets", "cli", "__init__", "urdf",
              "resources", "runtime", "units", "files"}
# The pure solver is fine anywhere (like scipy.optimize); models, data and rendering are world-only.
ALLOWED = {"mujoco.minimize"}
# the packages whose modules must not import another module's private (_name) names
PUBLIC_FACES = ("world", "instrument", "evaluation", "runner", "commands", "foundation", "importers")
RERUN_MODULE = "twin/evaluation/recording.py"


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


def _private_imports(packages=PUBLIC_FACES):
    """``from module import _name`` of another module, in the modules of ``packages``."""
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        pkg = "foundation" if len(rel.parts) == 1 else rel.parts[0]
        if pkg not in packages:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        bad.append(f"{path.relative_to(ROOT.parent)} imports {node.module}.{a.name}")
    return bad


def test_no_module_imports_private_names():
    """The world, instrument, evaluation, runner, commands, importers and foundation modules use each other's public
    names only."""
    assert _private_imports() == []


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
