"""The plumbing of the compiled momentum update (``hild/dynamics/_momentum.c``): MuJoCo's C functions and the
observer's arrays, by address.

The C side includes no MuJoCo header, so it builds without MuJoCo's sources and cannot disagree with the installed
MuJoCo about a struct's layout: every array it touches is handed over as the address of a numpy view into
``MjData`` (or of the observer's own array), and MuJoCo's functions as their addresses in the very library the
``mujoco`` package loaded (``dlopen`` of the same file returns the loaded one). Only the public C signatures of
``mj_kinematics``, ``mj_comPos``, ``mj_makeM``, ``mj_fwdPosition``, ``mj_fwdVelocity``, ``mj_rne`` and
``mj_mulM`` are relied on; the observer checks the result against its Python path before it uses it.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

if TYPE_CHECKING:
    from hild.dynamics.momentum import MomentumObserver

FUNCTIONS = ("mj_kinematics", "mj_comPos", "mj_makeM", "mj_fwdPosition", "mj_fwdVelocity", "mj_rne", "mj_mulM")


@functools.cache
def mujoco_functions() -> tuple[tuple[int, ...], str]:
    """The addresses of ``FUNCTIONS`` in the loaded MuJoCo library, or () and why not."""
    libraries = sorted(Path(mujoco.__file__).parent.glob("libmujoco.so*"))
    if not libraries:
        return (), f"no libmujoco.so beside the mujoco package ({Path(mujoco.__file__).parent})"
    try:
        library = ctypes.CDLL(str(libraries[-1]))
        return tuple(ctypes.cast(getattr(library, f), ctypes.c_void_p).value or 0 for f in FUNCTIONS), ""
    except (OSError, AttributeError) as exc:
        return (), f"MuJoCo's C functions not found: {exc}"


def momentum_kernel(observer: MomentumObserver) -> tuple[Any, str]:
    """A compiled update bound to ``observer``'s model, data and arrays, or None and why not."""
    try:
        from hild.dynamics._momentum import Kernel
    except ImportError as exc:
        return None, f"the compiled update was not built: {exc}"
    functions, why = mujoco_functions()
    if not functions or not all(functions):
        return None, why or "a MuJoCo function has no address"
    m, d = observer.model, observer.data
    if not hasattr(m, "_address") or not hasattr(d, "_address"):
        return None, f"mujoco {mujoco.__version__} does not expose its structs' addresses"
    arrays = (
        d.qpos,
        d.qvel,
        d.qfrc_bias,
        d.qfrc_passive,
        d.cvel.reshape(-1),  # views, as the Python path's fill(0.0) writes them
        d.cdof_dot.reshape(-1),
        observer._step,
        observer._mass_prev,
        observer._mass_now,
        observer._gravity_full,
        observer.residual,
        observer.gravity,
    )
    if any(not (a.flags.c_contiguous and a.dtype == np.float64) for a in arrays):
        return None, "an array is not contiguous float64"
    keep = (m, d, arrays)
    try:
        kernel = Kernel(
            m._address,
            d._address,
            functions,
            arrays,
            [int(a) for a in observer._qposadr],
            [int(a) for a in observer._dofadr],
            observer.gain,
            observer._staged,
            observer._with_gravity,
            keep,
        )
    except (ValueError, TypeError, MemoryError) as exc:
        return None, f"the compiled update refused the observer: {exc}"
    return kernel, ""
