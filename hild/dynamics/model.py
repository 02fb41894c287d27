"""Loading the arm model with MuJoCo's own loader and finding its joints: shared by the twin, the emulator's
plant, the gravity feed-forward, the kinematics and the importer's checks, so all read a file the same way."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np

# Joint types that own exactly one position and one velocity coordinate.
SCALAR_JOINT_TYPES = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def load_model(path: Path, exclude_contacts: Sequence[tuple[str, str]] = ()) -> mujoco.MjModel:
    """Load and compile an MJCF (``.xml``) or URDF (``.urdf``) model with MuJoCo's loader.

    ``exclude_contacts``: body pairs whose contacts MuJoCo ignores (``<contact><exclude>``), added before the model
    is compiled, since a URDF cannot say it. Raises ``ValueError`` naming the file, with MuJoCo's own message, when
    the file is missing or does not compile, or a pair names a body the model does not have.
    """
    path = Path(path)
    if path.suffix.lower() not in (".xml", ".urdf", ".mjcf"):
        raise ValueError(f"model {path}: expected an MJCF (.xml) or URDF (.urdf) file")
    if not path.is_file():
        raise ValueError(f"model {path}: file not found")
    try:
        if not exclude_contacts:
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
    try:
        return spec.compile()
    except Exception as exc:
        raise ValueError(f"model {path}: MuJoCo could not load it: {exc}") from exc


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
