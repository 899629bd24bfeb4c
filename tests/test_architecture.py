"""The one-way data flow, checked on the import graph (AST of every module under twin/)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "twin"

# layer -> packages/modules it must not import
FORBIDDEN = {
    "foundation": ("twin.world", "twin.instrument", "twin.estimator", "twin.diagnosis", "twin.evaluation", "mujoco", "rerun", "cv2"),
    "world": ("twin.instrument", "twin.estimator", "twin.diagnosis", "twin.evaluation", "rerun"),
    "instrument": ("twin.world", "twin.estimator", "twin.diagnosis", "twin.evaluation", "mujoco", "rerun"),
    "estimator": ("twin.world", "twin.instrument", "twin.diagnosis", "twin.evaluation", "mujoco", "rerun", "cv2"),
    "diagnosis": ("twin.world", "twin.instrument", "twin.evaluation", "mujoco", "rerun", "cv2"),
}
FOUNDATION = {"transforms", "kinematics", "robots", "camera", "dataset", "benchio", "presets", "cli", "__init__", "urdf",
              "mocap"}
# The pure solver is fine anywhere (like scipy.optimize); models, data and rendering are world-only.
ALLOWED = {"mujoco.minimize"}
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
