"""Loading the arm model with MuJoCo's own loader and finding its joints: shared by the twin, the emulator's
plant, the gravity feed-forward, the kinematics and the importer's checks, so all read a file the same way."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hild.arrays import contiguous_slice

# Joint types that own exactly one position and one velocity coordinate.
SCALAR_JOINT_TYPES = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
# MuJoCo sensors at a site that give each hild sensor type its values, in the order hild's interfaces list them
SITE_SENSORS: dict[str, tuple[int, ...]] = {
    "force_torque": (int(mujoco.mjtSensor.mjSENS_FORCE), int(mujoco.mjtSensor.mjSENS_TORQUE)),
    "imu": (
        int(mujoco.mjtSensor.mjSENS_FRAMEQUAT),
        int(mujoco.mjtSensor.mjSENS_GYRO),
        int(mujoco.mjtSensor.mjSENS_ACCELEROMETER),
    ),
}


@dataclass(frozen=True, slots=True)
class SceneObject:
    """A rigid primitive added to the model's world: a box to grasp, a table, a wall (a URDF cannot hold one)."""

    name: str
    shape: str  # "box" | "sphere" | "cylinder"
    size: tuple[float, ...]  # MuJoCo's half-sizes: box (x, y, z), sphere (r,), cylinder (r, half-height)
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    mass: float = 0.1
    friction: float = 1.0
    fixed: bool = False  # welded to the world (a table) instead of free (a box)
    rgba: tuple[float, float, float, float] = (0.8, 0.5, 0.2, 1.0)


_SHAPES = {
    "box": mujoco.mjtGeom.mjGEOM_BOX,
    "sphere": mujoco.mjtGeom.mjGEOM_SPHERE,
    "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
}


@dataclass(frozen=True)
class SensorMount:
    """A hild sensor on the model: ``kind`` (force_torque | imu) at ``site``, or, when ``site`` is None, at a site
    ``mounted_site(name)`` added at the origin of body ``body``. The MuJoCo sensors ``SITE_SENSORS[kind]`` at that
    site are added unless the model already has them."""

    name: str
    kind: str
    body: str
    site: str | None = None

    @property
    def site_name(self) -> str:
        return self.site or mounted_site(self.name)


def mounted_site(sensor: str) -> str:
    """The name of the site added for a hild sensor that names no site of the model."""
    return f"hild_{sensor}"


def load_model(
    path: Path,
    exclude_contacts: Sequence[tuple[str, str]] = (),
    sensors: Sequence[SensorMount] = (),
    objects: Sequence[SceneObject] = (),
) -> mujoco.MjModel:
    """Load and compile an MJCF (``.xml``) or URDF (``.urdf``) model with MuJoCo's loader.

    ``exclude_contacts``: body pairs whose contacts MuJoCo ignores (``<contact><exclude>``), added before the model
    is compiled, since a URDF cannot say it. ``sensors``: hild sensors whose MuJoCo sensors (and site) are added
    when the model lacks them (a URDF cannot declare them either). ``objects``: primitives added to the world (after
    the model's own bodies, so its joints keep their addresses). Raises ``ValueError`` naming the file, with
    MuJoCo's own message, when the file is missing or does not compile, a pair or a sensor names a body or site the
    model does not have, or an object's name is taken.
    """
    path = Path(path)
    if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
        raise ValueError(f"model {path}: expected an MJCF (.xml) or URDF (.urdf) file")
    if not path.is_file():
        raise ValueError(f"model {path}: file not found")
    try:
        if not exclude_contacts and not sensors and not objects:
            return mujoco.MjModel.from_xml_path(str(path))
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # mujoco raises ValueError; be robust to other binding errors
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc
    bodies = {body.name for body in spec.bodies}
    unknown = sorted({name for pair in exclude_contacts for name in pair} - bodies)
    if unknown:
        raise ValueError(f"model {path}: exclude_contacts names bodies it does not have: {', '.join(unknown)}")
    for first, second in exclude_contacts:
        spec.add_exclude(bodyname1=first, bodyname2=second)
    taken = sorted({o.name for o in objects} & bodies)
    if taken or len({o.name for o in objects}) != len(objects):
        raise ValueError(f"model {path}: object names must be new and distinct: {', '.join(taken) or 'repeated'}")
    for item in objects:
        _add_object(spec, item)
    for mount in sensors:
        _mount(spec, mount, path)
    try:
        return spec.compile()
    except Exception as exc:
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc


def _add_object(spec: mujoco.MjSpec, item: SceneObject) -> None:
    body = spec.worldbody.add_body(name=item.name, pos=list(item.pos), quat=list(item.quat))
    if not item.fixed:
        body.add_freejoint(name=item.name)
    body.add_geom(
        name=item.name,
        type=_SHAPES[item.shape],
        size=[*item.size, *([0.0] * (3 - len(item.size)))],
        mass=item.mass,
        friction=[item.friction, 0.005, 0.0001],
        condim=4,  # torsional friction too: a grasped object does not spin out of the fingers
        rgba=list(item.rgba),
    )


def _mount(spec: mujoco.MjSpec, mount: SensorMount, path: Path) -> None:
    """Add ``mount``'s site (when it names none) and the MuJoCo sensors its site lacks."""
    sites = {site.name for site in spec.sites}
    if mount.site is not None:
        if mount.site not in sites:
            known = ", ".join(sorted(n for n in sites if n)) or "none"
            raise ValueError(f"model {path}: sensor {mount.name}: no site {mount.site!r} (sites: {known})")
    else:
        body = spec.body(mount.body)
        if body is None:
            known = ", ".join(b.name for b in spec.bodies if b.name)
            raise ValueError(
                f"model {path}: sensor {mount.name}: frame {mount.body!r} is not a body of the model (bodies: "
                f"{known}); a URDF link on a fixed joint is merged into its parent unless the URDF's <mujoco> "
                'element sets <compiler fusestatic="false"/>'
            )
        body.add_site(name=mount.site_name)
    present = {int(s.type) for s in spec.sensors if s.objname == mount.site_name}
    for kind in SITE_SENSORS[mount.kind]:
        if kind not in present:
            spec.add_sensor(
                name=f"{mount.site_name}_{mujoco.mjtSensor(kind).name.removeprefix('mjSENS_').lower()}",
                type=mujoco.mjtSensor(kind),
                objtype=mujoco.mjtObj.mjOBJ_SITE,
                objname=mount.site_name,
            )


def site_sensor_addresses(model: mujoco.MjModel, mount: SensorMount) -> list[int]:
    """Per MuJoCo sensor of ``SITE_SENSORS[mount.kind]``, the address of its values in ``sensordata``."""
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, mount.site_name)
    out = []
    for kind in SITE_SENSORS[mount.kind]:
        found = [
            i
            for i in range(model.nsensor)
            if int(model.sensor_type[i]) == kind
            and int(model.sensor_objtype[i]) == int(mujoco.mjtObj.mjOBJ_SITE)
            and int(model.sensor_objid[i]) == site
        ]
        if site < 0 or not found:
            raise ValueError(f"sensor {mount.name}: no {mujoco.mjtSensor(kind).name} sensor at site {mount.site_name}")
        out.append(int(model.sensor_adr[found[0]]))
    return out


def joint_names(model: mujoco.MjModel) -> list[str]:
    """Names of the model's joints, in model order (unnamed joints as ``<unnamed #i>``)."""
    return [model.joint(i).name or f"<unnamed #{i}>" for i in range(model.njnt)]


def scalar_joint_addresses(
    model: mujoco.MjModel, names: Sequence[str], what: str = "model"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map joint names to ``(joint ids, qpos addresses, dof addresses)``.

    Every name must be a hinge or slide joint of ``model``; otherwise ``ValueError`` lists the names that are
    missing (or of the wrong type) and the model's joint names.
    """
    ids: list[int] = []
    missing: list[str] = []
    wrong_type: list[str] = []
    for name in names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            missing.append(name)
        elif int(model.jnt_type[jid]) not in SCALAR_JOINT_TYPES:
            wrong_type.append(name)
        else:
            ids.append(jid)
    if missing or wrong_type:
        parts = []
        if missing:
            parts.append(f"joints not in the {what}: {', '.join(missing)}")
        if wrong_type:
            parts.append(f"not hinge/slide joints: {', '.join(wrong_type)}")
        raise ValueError(f"{'; '.join(parts)} (the {what} has joints: {', '.join(joint_names(model)) or 'none'})")
    if len(set(ids)) != len(ids):
        raise ValueError(f"joint names repeat: {', '.join(names)}")
    jid = np.asarray(ids, dtype=np.intp)
    return jid, model.jnt_qposadr[jid].astype(np.intp), model.jnt_dofadr[jid].astype(np.intp)


@dataclass(frozen=True)
class JointCoupling:
    """A MuJoCo joint equality (``mjEQ_JOINT`` with a second joint) — what MuJoCo's URDF loader makes of
    ``<mimic>``: ``y − y0 = a0 + a1·(x − x0) + a2·(x − x0)² + a3·(x − x0)³ + a4·(x − x0)⁴``, with ``y`` the
    follower, ``x`` the leader and ``y0, x0`` their reference positions (qpos0)."""

    follower: int  # joint ids
    leader: int
    polycoef: tuple[float, float, float, float, float]
    equality: int = -1  # the equality's id in the model (its solref, its data)

    def position(self, model: mujoco.MjModel, leader_position: float) -> float:
        """The follower's position the equality holds it at, for the leader at ``leader_position``."""
        x = leader_position - float(model.qpos0[model.jnt_qposadr[self.leader]])
        y = sum(a * x**k for k, a in enumerate(self.polycoef))
        return float(model.qpos0[model.jnt_qposadr[self.follower]]) + y

    def rate(self, model: mujoco.MjModel, leader_position: float) -> float:
        """dy/dx at ``leader_position``: the follower's velocity per unit of the leader's."""
        x = leader_position - float(model.qpos0[model.jnt_qposadr[self.leader]])
        return sum(k * a * x ** (k - 1) for k, a in enumerate(self.polycoef) if k)


def joint_couplings(model: mujoco.MjModel) -> list[JointCoupling]:
    """The model's active joint-to-joint equalities, leaders before their followers (a chain of mimic joints is
    resolved link by link); an equality whose leader follows it back (a cycle) is left out."""
    found = [
        JointCoupling(
            int(model.eq_obj1id[i]), int(model.eq_obj2id[i]), tuple(float(a) for a in model.eq_data[i, :5]), i
        )
        for i in range(model.neq)
        if int(model.eq_type[i]) == int(mujoco.mjtEq.mjEQ_JOINT) and model.eq_obj2id[i] >= 0 and model.eq_active0[i]
    ]
    ordered: list[JointCoupling] = []
    followers = {c.follower for c in found}
    placed: set[int] = set()
    while True:
        ready = [c for c in found if c not in ordered and (c.leader not in followers or c.leader in placed)]
        if not ready:
            return ordered
        ordered += ready
        placed |= {c.follower for c in ready}


def couple_joints(
    model: mujoco.MjModel, data: mujoco.MjData, couplings: Sequence[JointCoupling] | None = None
) -> list[JointCoupling]:
    """Put every joint a joint equality couples where its leader puts it (position and velocity), chains
    included: a start pose that sets only the leader (``initial_positions``, a keyframe written for the driven
    joints) would otherwise leave every coupling violated, and the solver snaps the linkage in the first steps.
    The caller runs ``mj_forward`` afterwards. ``couplings``: :func:`joint_couplings` of the model, when the
    caller keeps them for repeated use. Returns the couplings applied."""
    couplings = joint_couplings(model) if couplings is None else list(couplings)
    for c in couplings:
        x = float(data.qpos[model.jnt_qposadr[c.leader]])
        data.qpos[model.jnt_qposadr[c.follower]] = c.position(model, x)
        data.qvel[model.jnt_dofadr[c.follower]] = c.rate(model, x) * float(data.qvel[model.jnt_dofadr[c.leader]])
    return couplings


def linear_coupling(model: mujoco.MjModel, follower: str) -> tuple[str, float, float] | None:
    """``(leader joint, multiplier, offset)`` of a joint the model couples linearly to another — through a chain
    of such couplings to the first leader that follows nothing — in absolute positions
    (``y = multiplier·x + offset``); None when no joint equality drives it, or one is not linear."""
    by_follower = {c.follower: c for c in joint_couplings(model)}
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, follower)
    if jid < 0 or jid not in by_follower:
        return None
    multiplier, offset = 1.0, 0.0
    while jid in by_follower:
        c = by_follower[jid]
        if any(c.polycoef[2:]):
            return None
        y0 = float(model.qpos0[model.jnt_qposadr[c.follower]])
        x0 = float(model.qpos0[model.jnt_qposadr[c.leader]])
        a0, a1 = c.polycoef[0], c.polycoef[1]
        # y = y0 + a0 + a1·(x − x0); composed with what is known of y so far: result = multiplier·y + offset
        offset += multiplier * (y0 + a0 - a1 * x0)
        multiplier *= a1
        jid = c.leader
    return model.joint(jid).name, multiplier, offset


def stiffen_couplings(model: mujoco.MjModel, timestep: float) -> int:
    """Hold every joint coupling (a URDF ``<mimic>``) as stiff as the physics step allows: MuJoCo's default
    constraint time constant (0.02 s) lets a gripper's mimic finger yield by tenths of a radian under a grasp,
    where the real linkage is rigid; 2 × timestep is the stiffest MuJoCo integrates stably. Returns how many."""
    couplings = joint_couplings(model)
    for c in couplings:
        model.eq_solref[c.equality] = (2.0 * timestep, 1.0)
    return len(couplings)


class JointSlots:
    """The robot's joints' entries in a per-qpos (or per-dof) array of an ``MjData``: a prebuilt view when they are
    one block in model order (the usual case: a copy through it is cheaper than put), else their addresses. Writing
    through it allocates nothing, so the cycle can pose a private ``MjData`` with it."""

    def __init__(self, array: np.ndarray, addresses: np.ndarray) -> None:
        self._array, self._addresses = array, addresses
        block = contiguous_slice(addresses)
        self._view = array[block] if block is not None else None

    def write(self, values: np.ndarray) -> None:
        """The joints' ``values`` (in the robot's joint order) into the array."""
        if self._view is not None:
            np.copyto(self._view, values)
        else:
            np.put(self._array, self._addresses, values)
