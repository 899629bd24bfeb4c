"""MJCF of the twin: a robot generated from a parameter set, composed with the static scene files.

The robot's body frames follow the kinematic chain of ``twin.kinematics`` exactly, in either convention:
body ``i`` (1..6) *is* frame ``i`` of :func:`twin.kinematics.link_frames`. Each joint transform of the
model is ``L_i(q_i) = B_i · G_i(q_i)`` where ``B_i = L_i(0)`` (the body's ``pos``/``quat`` relative to its
parent) and ``G_i(q) = B_i^{-1} L_i(q)`` is a rotation by ``q`` about a fixed line of body ``i`` (the hinge
joint's ``axis`` through ``pos``). The line is read off ``G_i(pi/2)``: its rotation vector gives the
axis, and the anchor is the minimum-norm solution of ``(I - R) c = t``. This works for any ordering of
the elementary operations (``mdh`` puts the rotation last but for beta, ``dh`` puts translations after
it) without restating the conventions here. MuJoCo's ``qpos`` is then the joint value ``q`` of the
library (the ``theta`` offsets live in ``B_i``).

The robot base body sits at ``robot.base2meas`` in the MuJoCo world frame (the world calls this
``base2world``), the ``plate`` body at ``robot.tool2flange`` in the flange body, with a site ``plate``
at its origin (the tool frame) and sites ``sphere0..2`` at the sphere centres.

Static parts (rendering settings, materials, rig with cameras and lights, board, backdrop) are the package's
data files ``models/*.xml`` (the package ``twin.models``, :func:`twin.resources.model_file`);
:func:`compose_twin_xml` merges them with the generated robot and rewrites the config-dependent attributes
(camera placement and field of view, backdrop distance, board size and texture).
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from ..kinematics import N_JOINTS, RobotModel, link_frames, link_transforms
from ..resources import model_file
from ..transforms import invert_transform, matrix_to_quat_wxyz, matrix_to_rotvec

__all__ = [
    "JointGeometry",
    "joint_geometry",
    "RobotVisual",
    "robot_body_element",
    "compose_twin_xml",
    "GROUP_SCENE",
    "GROUP_ROBOT",
    "GROUP_PLATE",
    "GROUP_BOARD",
    "GROUP_PROBE",
    "GROUP_BACKDROP",
]

# Geom groups: the renderer shows the groups each kind of image needs (pairs hide the board, board views
# hide the arm and plate, the probe image shows the probe only).
GROUP_SCENE, GROUP_ROBOT, GROUP_PLATE, GROUP_BOARD, GROUP_PROBE, GROUP_BACKDROP = 0, 1, 2, 3, 4, 5


def _f(x: float) -> str:
    """Full-precision float for XML (repr round-trips exactly)."""
    return repr(float(x))


def _vec(v) -> str:
    return " ".join(_f(x) for x in np.asarray(v, dtype=float).reshape(-1))


@dataclass(frozen=True)
class JointGeometry:
    """Body ``i``'s placement in its parent and its hinge line, all in SI.

    ``body2parent`` ``(4, 4)`` = ``L_i(0)``; ``axis`` ``(3,)`` unit vector and ``anchor`` ``(3,)`` [m] of the
    hinge in body ``i``'s own frame.
    """

    body2parent: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray


def joint_geometry(robot: RobotModel) -> list[JointGeometry]:
    """Per-joint body placement and hinge line (see the module docstring for the derivation)."""
    zeros = np.zeros((1, N_JOINTS))
    L0 = link_transforms(robot, zeros)[0]
    out = []
    for i in range(N_JOINTS):
        q = zeros.copy()
        q[0, i] = np.pi / 2
        G = invert_transform(L0[i]) @ link_transforms(robot, q)[0, i]
        rv = matrix_to_rotvec(G[:3, :3])
        angle = np.linalg.norm(rv)
        if abs(angle - np.pi / 2) > 1e-9:
            raise ValueError(f"joint {i + 1} of {robot.name!r} does not act as a rotation by q (got {angle} rad)")
        axis = rv / angle
        anchor = np.linalg.lstsq(np.eye(3) - G[:3, :3], G[:3, 3], rcond=None)[0]
        out.append(JointGeometry(L0[i].copy(), axis, anchor))
    return out


@dataclass(frozen=True)
class RobotVisual:
    """Visual sizes [m] and masses [kg] of the arm (plausible IRB-1200-class magnitudes).

    ``link_radius[k]`` is the capsule radius of the segment between frame origins ``k`` and ``k+1``;
    ``housing`` ``(radius, half_length)`` per joint is the motor housing drawn along the joint axis;
    ``masses`` per body (base, links 1..6) sum to the arm's weight (the IRB 1200-7/0.7 weighs 52 kg).
    """

    base_radius: float = 0.11
    base_height: float = 0.20
    link_radius: tuple[float, ...] = (0.085, 0.07, 0.06, 0.048, 0.04, 0.035)
    housing: tuple[tuple[float, float], ...] = (
        (0.095, 0.06), (0.08, 0.09), (0.065, 0.075), (0.05, 0.05), (0.045, 0.055), (0.032, 0.012),
    )
    masses: tuple[float, ...] = (15.0, 11.5, 9.5, 8.0, 4.5, 2.5, 1.0)
    plate_radius: float = 0.095
    plate_thickness: float = 0.012
    post_radius: float = 0.004
    plate_mass: float = 0.85
    sphere_mass: float = 0.033  # 25.4 mm alumina ball

    @property
    def arm_mass(self) -> float:
        return float(sum(self.masses))


def _capsule_between(p0: np.ndarray, p1: np.ndarray, radius: float) -> dict | None:
    if np.linalg.norm(p1 - p0) < 1e-3:
        return None
    return {"kind": "capsule", "p0": np.asarray(p0, float), "p1": np.asarray(p1, float), "radius": float(radius)}


def _cylinder_along(centre: np.ndarray, axis: np.ndarray, radius: float, half_length: float) -> dict:
    a = np.asarray(axis) / np.linalg.norm(axis)
    return {"kind": "cylinder", "p0": centre - half_length * a, "p1": centre + half_length * a, "radius": float(radius)}


def _geom_volume(g: dict) -> float:
    r = g["radius"]
    h = np.linalg.norm(g["p1"] - g["p0"])
    if g["kind"] == "capsule":
        return np.pi * r * r * h + 4.0 / 3.0 * np.pi * r**3
    return np.pi * r * r * h


def _frame_along(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Rotation ``(3, 3)`` whose z axis runs from ``p0`` to ``p1``."""
    z = (p1 - p0) / np.linalg.norm(p1 - p0)
    x = np.cross(z, [1.0, 0, 0]) if abs(z[0]) < 0.9 else np.cross(z, [0, 1.0, 0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _solid_mesh(g: dict, n: int = 40, rings: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` and outward-wound faces ``(F, 3)`` of a cylinder or capsule between two points.

    The arm's links are drawn as these light meshes rather than MuJoCo primitives: primitives share the
    fine tessellation the spheres need (``numslices=128``), which would triple the render time of a frame
    for no benefit on the arm.
    """
    p0, p1, r = g["p0"], g["p1"], g["radius"]
    h = np.linalg.norm(p1 - p0)
    R = _frame_along(p0, p1)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    circle = np.stack([np.cos(ang), np.sin(ang), np.zeros(n)], axis=1)
    verts: list[np.ndarray] = []
    faces: list[tuple[int, int, int]] = []
    if g["kind"] == "cylinder":
        verts = [circle * r, circle * r + [0, 0, h], np.array([[0, 0, 0.0], [0, 0, h]])]
        V = np.concatenate(verts)
        c0, c1 = 2 * n, 2 * n + 1
        for i in range(n):
            j = (i + 1) % n
            faces += [(i, j, n + j), (i, n + j, n + i), (c0, j, i), (c1, n + i, n + j)]
    else:
        # rings of latitude: bottom hemisphere (z <= 0), top hemisphere (z >= h), poles last
        lat = np.concatenate([np.linspace(-np.pi / 2, 0, rings + 1)[1:], np.linspace(0, np.pi / 2, rings + 1)[:-1]])
        zoff = np.concatenate([np.zeros(rings), np.full(rings, h)])
        for la, zo in zip(lat, zoff):
            verts.append(np.stack([np.cos(la) * r * np.cos(ang), np.cos(la) * r * np.sin(ang),
                                   np.full(n, zo + r * np.sin(la))], axis=1))
        verts.append(np.array([[0, 0, -r], [0, 0, h + r]]))
        V = np.concatenate(verts)
        nr = 2 * rings
        south, north = nr * n, nr * n + 1
        for k in range(nr - 1):
            for i in range(n):
                j = (i + 1) % n
                a, b, c, d = k * n + i, k * n + j, (k + 1) * n + j, (k + 1) * n + i
                faces += [(a, b, c), (a, c, d)]
        for i in range(n):
            j = (i + 1) % n
            faces += [(south, j, i), (north, (nr - 1) * n + i, (nr - 1) * n + j)]
    F = np.array(faces, dtype=int)
    # orient every face outward (the solids are convex)
    Vw = V @ R.T + p0
    centre = Vw.mean(axis=0)
    tri = Vw[F]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", nrm, tri.mean(axis=1) - centre) < 0
    F[flip] = F[flip][:, [0, 2, 1]]
    return Vw, F


def _rigid_owner(robot: RobotModel, k: int) -> int:
    """Highest body index in which the segment between frame origins ``k`` and ``k+1`` is rigid."""
    rng = np.random.default_rng(12345)
    qs = rng.uniform(-2.0, 2.0, size=(3, N_JOINTS))
    F = np.array([robot_frames_base(robot, q) for q in qs])  # (3, 7, 4, 4)
    for body in (k + 1, k):
        ok = True
        for end in (k, k + 1):
            local = [invert_transform(F[s, body]) @ F[s, end][:, 3] for s in range(len(qs))]
            if max(np.linalg.norm(local[s] - local[0]) for s in range(len(qs))) > 1e-9:
                ok = False
        if ok:
            return body
    raise ValueError(f"segment between frames {k} and {k + 1} of {robot.name!r} is rigid in no body")


def robot_frames_base(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    """Frames 0..6 ``(7, 4, 4)`` in the robot base frame (thin wrapper used for the visual layout)."""
    return link_frames(robot, np.asarray(q, dtype=float)[None])[0]


def _element(tag: str, **attrs) -> ET.Element:
    return ET.Element(tag, {k: str(v) for k, v in attrs.items() if v is not None})


def robot_body_element(
    robot: RobotModel,
    spheres_tool: np.ndarray,
    sphere_diameter: float,
    visual: RobotVisual | None = None,
    *,
    joint_damping: float = 20.0,
    joint_armature: float = 0.2,
) -> tuple[ET.Element, list[ET.Element]]:
    """The ``<body name="robot_base">`` subtree of ``robot`` carrying the plate, and its mesh assets.

    ``spheres_tool`` ``(3, 3)`` [m]: sphere centres in the plate (tool) frame; ``sphere_diameter`` [m].
    Geoms take no part in contacts (``contype=conaffinity=0``): the twin needs kinematics, rendering and
    gravity statics, not collisions. Joint limits are the model's commanded-joint limits.
    """
    visual = visual or RobotVisual()
    meshes: list[ET.Element] = []  # mesh assets of the arm, returned beside the body (see robot_assets)
    spheres_tool = np.asarray(spheres_tool, dtype=float)
    if spheres_tool.shape != (3, 3) or not np.all(np.isfinite(spheres_tool)):
        raise ValueError(f"spheres_tool must be a finite (3, 3) array [m], got shape {spheres_tool.shape}")
    if not (np.isfinite(sphere_diameter) and sphere_diameter > 0):
        raise ValueError(f"sphere_diameter must be positive [m], got {sphere_diameter!r}")
    jg = joint_geometry(robot)
    F0 = robot_frames_base(robot, np.zeros(N_JOINTS))

    # Visual geoms per body (0 = base), in that body's frame.
    geoms: list[list[dict]] = [[] for _ in range(N_JOINTS + 1)]
    geoms[0].append(_cylinder_along(np.array([0, 0, 0.5 * visual.base_height]), np.array([0, 0, 1.0]),
                                    visual.base_radius, 0.5 * visual.base_height))
    geoms[0][-1]["material"] = "robot"
    for k in range(N_JOINTS):
        owner = _rigid_owner(robot, k)
        inv = invert_transform(F0[owner])
        p0 = (inv @ F0[k][:, 3])[:3]
        p1 = (inv @ F0[k + 1][:, 3])[:3]
        g = _capsule_between(p0, p1, visual.link_radius[k])
        if g is not None and k == N_JOINTS - 1:
            # the last link ends in the flange: a cylinder stopping at the flange disc, not a capsule whose
            # cap would poke through the plate
            d = (p1 - p0) / np.linalg.norm(p1 - p0)
            g = {"kind": "cylinder", "p0": p0, "p1": p1 - 0.012 * d, "radius": visual.link_radius[k]}
        if g is not None:
            g["material"] = "robot"
            geoms[owner].append(g)
    for i in range(N_JOINTS - 1):  # joint 6's drive sits in the wrist; a housing there would poke through the plate
        r, h = visual.housing[i]
        g = _cylinder_along(jg[i].anchor, jg[i].axis, r, h)
        g["material"] = "robot_dark" if i in (1, 2) else "robot"
        geoms[i + 1].append(g)

    def add_geoms(body: ET.Element, items: list[dict], mass: float, name: str) -> None:
        vols = np.array([_geom_volume(g) for g in items])
        for n, (g, v) in enumerate(zip(items, vols)):
            V, F = _solid_mesh(g)
            mesh_name = f"{name}_mesh{n}"
            meshes.append(_element("mesh", name=mesh_name, vertex=_vec(V), face=" ".join(str(i) for i in F.ravel())))
            body.append(_element("geom", name=f"{name}_g{n}", type="mesh", mesh=mesh_name, material=g["material"],
                                 group=GROUP_ROBOT, contype=0, conaffinity=0, mass=_f(mass * v / vols.sum())))

    base = _element("body", name="robot_base", pos=_vec(robot.base2meas[:3, 3]),
                    quat=_vec(matrix_to_quat_wxyz(robot.base2meas[:3, :3])))
    add_geoms(base, geoms[0], visual.masses[0], "base")
    parent = base
    for i in range(N_JOINTS):
        T = jg[i].body2parent
        body = _element("body", name=f"link{i + 1}", pos=_vec(T[:3, 3]), quat=_vec(matrix_to_quat_wxyz(T[:3, :3])))
        body.append(
            _element(
                "joint", name=f"joint{i + 1}", type="hinge", pos=_vec(jg[i].anchor), axis=_vec(jg[i].axis),
                range=_vec([robot.q_min[i], robot.q_max[i]]), limited="true",
                damping=_f(joint_damping), armature=_f(joint_armature),
            )
        )
        body.append(_element("site", name=f"frame{i + 1}", pos="0 0 0", size="0.005", group=GROUP_ROBOT))
        add_geoms(body, geoms[i + 1], visual.masses[i + 1], f"link{i + 1}")
        parent.append(body)
        parent = body
    def mesh_geom(body: ET.Element, g: dict, name: str, material: str, group: int, mass: float, n: int = 40) -> None:
        V, F = _solid_mesh(g, n=n)
        meshes.append(_element("mesh", name=f"{name}_mesh", vertex=_vec(V), face=" ".join(str(i) for i in F.ravel())))
        body.append(_element("geom", name=name, type="mesh", mesh=f"{name}_mesh", material=material, group=group,
                             contype=0, conaffinity=0, mass=_f(mass)))

    # Flange face at frame 6's origin (the disc sits just behind it).
    mesh_geom(parent, {"kind": "cylinder", "p0": np.array([0, 0, -0.012]), "p1": np.array([0, 0, -0.0005]),
                       "radius": 0.0315}, "flange", "robot_dark", GROUP_ROBOT, 0.05)
    parent.append(_element("site", name="flange", pos="0 0 0", size="0.005", group=GROUP_ROBOT))

    # The plate: a dark disc on the flange, posts, three matte ceramic spheres.
    tool = robot.tool2flange
    plate = _element("body", name="plate", pos=_vec(tool[:3, 3]), quat=_vec(matrix_to_quat_wxyz(tool[:3, :3])))
    plate.append(_element("site", name="plate", pos="0 0 0", size="0.005", group=GROUP_PLATE))
    mesh_geom(plate, {"kind": "cylinder", "p0": np.zeros(3), "p1": np.array([0, 0, visual.plate_thickness]),
                      "radius": visual.plate_radius}, "plate_disc", "plate", GROUP_PLATE, visual.plate_mass, n=96)
    r = 0.5 * sphere_diameter
    for k, c in enumerate(spheres_tool):
        top = visual.plate_thickness
        bottom_of_sphere = c[2] - r
        if bottom_of_sphere - top > 1e-3:
            mesh_geom(plate, {"kind": "cylinder", "p0": np.array([c[0], c[1], top]),
                              "p1": np.array([c[0], c[1], bottom_of_sphere + 0.5 * r]), "radius": visual.post_radius},
                      f"post{k}", "plate", GROUP_PLATE, 0.005, n=16)
        # the spheres stay MuJoCo primitives: their tessellation (numslices/numstacks) keeps the outline exact
        plate.append(_element("geom", name=f"sphere{k}", type="sphere", pos=_vec(c), size=_f(r), material="ceramic",
                              group=GROUP_PLATE, contype=0, conaffinity=0, mass=_f(visual.sphere_mass)))
        plate.append(_element("site", name=f"sphere{k}", pos=_vec(c), size="0.002", group=GROUP_PLATE))
    parent.append(plate)
    return base, meshes


# ------------------------------------------------------------------------------------------------
# Composition with the static files
# ------------------------------------------------------------------------------------------------

def _load_static(name: str) -> ET.Element:
    return ET.fromstring(model_file(name).read_bytes())


def _merge_section(dst: ET.Element, src: ET.Element, tag: str) -> None:
    s = src.find(tag)
    if s is None:
        return
    d = dst.find(tag)
    if d is None:
        d = ET.SubElement(dst, tag)
    for child in list(s):
        d.append(copy.deepcopy(child))


def _box_mesh_faces(vertices: np.ndarray) -> list[int]:
    """Faces of an 8-vertex slab (0-3 front, 4-7 back), wound so every normal points outward."""
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    centre = vertices.mean(axis=0)
    faces: list[int] = []
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            v = vertices[list(tri)]
            n = np.cross(v[1] - v[0], v[2] - v[0])
            if np.dot(n, v.mean(axis=0) - centre) < 0:
                tri = (tri[0], tri[2], tri[1])
            faces += list(tri)
    return faces


@dataclass(frozen=True)
class ComposeOptions:
    """Config-dependent parts of the composed scene (all SI; poses in the rig frame, MuJoCo camera axes)."""

    camera_poses_rig: tuple[np.ndarray, np.ndarray]  # left, right cam2rig (4, 4), MuJoCo camera axes
    fovy_deg: tuple[float, float]  # left, right (ideal render)
    backdrop_distance: float  # [m] from the rig origin along -z
    backdrop_half_size: tuple[float, float]
    key_light_dir_rig: np.ndarray  # (3,)
    key_light_diffuse: float
    key_light_ambient: float
    headlight_diffuse: float
    headlight_ambient: float
    board_extent: tuple[float, float, float, float]  # x0, y0, x1, y1 [m] of the board face in the board frame
    board_thickness: float
    board_texture_file: str | None  # PNG next to the composed file (None: keep the placeholder)
    offwidth: int
    offheight: int
    probe_texture_file: str | None = None
    probe_half_size: float = 0.008
    board_texcoords: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0)  # u0, v0, u1, v1 of the face


def compose_twin_xml(robot: tuple[ET.Element, list[ET.Element]], opts: ComposeOptions, model_name: str = "twin") -> str:
    """The full twin MJCF (text): ``scene.xml`` + ``rig.xml`` + ``board.xml`` + the generated robot
    (``robot`` as returned by :func:`robot_body_element`)."""
    robot_body, robot_meshes = robot
    root = _load_static("scene.xml")
    root.set("model", model_name)
    rig = _load_static("rig.xml")
    board = _load_static("board.xml")
    for src in (rig, board):
        _merge_section(root, src, "asset")
        _merge_section(root, src, "worldbody")
    vis = root.find("visual")
    g = vis.find("global")
    g.set("offwidth", str(int(opts.offwidth)))
    g.set("offheight", str(int(opts.offheight)))
    hl = vis.find("headlight")
    hl.set("diffuse", _vec([opts.headlight_diffuse] * 3))
    hl.set("ambient", _vec([opts.headlight_ambient] * 3))

    wb = root.find("worldbody")
    rig_body = wb.find("./body[@name='rig']")
    for name, T, fovy in zip(("left", "right"), opts.camera_poses_rig, opts.fovy_deg):
        cam = rig_body.find(f"./camera[@name='{name}']")
        cam.set("pos", _vec(T[:3, 3]))
        cam.set("quat", _vec(matrix_to_quat_wxyz(T[:3, :3])))
        cam.set("fovy", _f(fovy))
    key = rig_body.find("./light[@name='key']")
    key.set("dir", _vec(opts.key_light_dir_rig))
    key.set("diffuse", _vec([opts.key_light_diffuse] * 3))
    key.set("ambient", _vec([opts.key_light_ambient] * 3))
    bd = rig_body.find("./geom[@name='backdrop']")
    bd.set("pos", _vec([0, 0, -opts.backdrop_distance]))
    bd.set("size", _vec([opts.backdrop_half_size[0], opts.backdrop_half_size[1], 0.005]))

    asset = root.find("asset")
    x0, y0, x1, y1 = opts.board_extent
    t = opts.board_thickness
    verts = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0],
                      [x0, y0, t], [x1, y0, t], [x1, y1, t], [x0, y1, t]], dtype=float)
    mesh = asset.find("./mesh[@name='board_face']")
    mesh.set("vertex", _vec(verts))
    mesh.set("face", " ".join(str(i) for i in _box_mesh_faces(verts)))
    # texcoord (u, v): v = 0 is the first row of the PNG, which is the board's -y (top) edge; the face may
    # use a sub-rectangle of a padded texture (see twin.world.board.board_texture_layout)
    u0, v0, u1, v1 = opts.board_texcoords
    mesh.set("texcoord", _vec([u0, v0, u1, v0, u1, v1, u0, v1] * 2))
    if opts.board_texture_file is not None:
        tex = asset.find("./texture[@name='board']")
        for k in list(tex.attrib):
            del tex.attrib[k]
        tex.set("name", "board")
        tex.set("type", "2d")
        tex.set("file", opts.board_texture_file)

    if opts.probe_texture_file is not None:
        # A fronto-parallel Gaussian spot on a mocap body: a diagnostic target whose image centroid is the
        # projection of a known point (see World.render_probe).
        s = opts.probe_half_size
        asset.append(_element("texture", name="probe", type="2d", file=opts.probe_texture_file))
        asset.append(_element("material", name="probe", texture="probe", rgba="1 1 1 1", specular="0", shininess="0"))
        pv = np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0],
                       [-s, -s, 0.001], [s, -s, 0.001], [s, s, 0.001], [-s, s, 0.001]])
        asset.append(_element("mesh", name="probe", vertex=_vec(pv), face=" ".join(str(i) for i in _box_mesh_faces(pv)),
                              texcoord="0 0  1 0  1 1  0 1  0 0  1 0  1 1  0 1"))
        pb = _element("body", name="probe", mocap="true", pos="0 0 -5")
        pb.append(_element("geom", name="probe", type="mesh", mesh="probe", material="probe", group=GROUP_PROBE,
                           contype=0, conaffinity=0, mass="0.001"))
        wb.append(pb)

    for mesh in robot_meshes:
        asset.append(mesh)
    wb.append(robot_body)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode")


def robot_mjcf_xml(robot: RobotModel, spheres_tool: np.ndarray | None = None, sphere_diameter: float | None = None,
                   model_name: str | None = None) -> str:
    """A standalone MJCF (text) of ``robot`` with its plate on ``scene.xml`` (no rig, no board).

    ``spheres_tool`` ``(3, 3)`` [m] / ``sphere_diameter`` [m] default to the nominal plate. The robot base
    sits at ``robot.base2meas`` in the MuJoCo world frame.
    """
    if spheres_tool is None or sphere_diameter is None:
        from ..dataset import default_plate

        plate = default_plate()
        spheres_tool = plate.spheres_flange if spheres_tool is None else spheres_tool
        sphere_diameter = plate.sphere_diameter if sphere_diameter is None else sphere_diameter
    body, meshes = robot_body_element(robot, spheres_tool, sphere_diameter)
    root = _load_static("scene.xml")
    root.set("model", model_name or f"robot_{robot.name}")
    asset = root.find("asset")
    for m in meshes:
        asset.append(m)
    root.find("worldbody").append(body)
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode")


__all__ += ["robot_mjcf_xml", "ComposeOptions"]
