"""Loading the arm model with MuJoCo's own loader and finding its joints: shared by the twin, the emulator's
plant, the gravity feed-forward, the kinematics and the importer's checks, so all read a file the same way."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

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
    path: Path, exclude_contacts: Sequence[tuple[str, str]] = (), sensors: Sequence[SensorMount] = ()
) -> mujoco.MjModel:
    """Load and compile an MJCF (``.xml``) or URDF (``.urdf``) model with MuJoCo's loader.

    ``exclude_contacts``: body pairs whose contacts MuJoCo ignores (``<contact><exclude>``), added before the model
    is compiled, since a URDF cannot say it. ``sensors``: hild sensors whose MuJoCo sensors (and site) are added
    when the model lacks them (a URDF cannot declare them either). Raises ``ValueError`` naming the file, with
    MuJoCo's own message, when the file is missing or does not compile, or a pair or a sensor names a body or site
    the model does not have.
    """
    path = Path(path)
    if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
        raise ValueError(f"model {path}: expected an MJCF (.xml) or URDF (.urdf) file")
    if not path.is_file():
        raise ValueError(f"model {path}: file not found")
    try:
        if not exclude_contacts and not sensors:
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
    for mount in sensors:
        _mount(spec, mount, path)
    try:
        return spec.compile()
    except Exception as exc:
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc


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
