"""Types, evaluation modes and warp set-up shared by the full-space kernels."""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from typing import Any

import warp as wp

from ..errors import ConfigError

__all__ = ["ACCEPTED_DEVICES", "KERNEL_MODULES", "Assembly", "assembly", "check_device_name", "load_kernels", "resolve_device", "warp_ready"]

ACCEPTED_DEVICES = ("auto", "cpu", "cuda", "cuda:N")
"""Device names :class:`~licrom.full.FullSim` accepts (``cuda:N`` is the N-th CUDA device; ``"auto"``,
or ``None``, is the first CUDA device when warp sees one, else the CPU)."""

if wp.config.log_level <= wp.LOG_INFO:  # no banner or module-load chatter on stdout
    wp.config.log_level = wp.LOG_WARNING

f64 = wp.float64
vec3d = wp.vec3d
mat33d = wp.mat33d

# What an evaluation kernel computes: the energy only, plus the gradient, plus the
# PSD-projected Hessian, plus the exact (unprojected) Hessian, or (contact only) the force
# on each contact point, written to its own slot instead of accumulated.
MODE_ENERGY = wp.constant(0)
MODE_GRADIENT = wp.constant(1)
MODE_HESSIAN = wp.constant(2)
MODE_RAW_HESSIAN = wp.constant(3)
MODE_FORCES = wp.constant(4)


@wp.struct
class Assembly:
    """Where the evaluation kernels add up what they compute: the energy's partial sums, the gradient and
    the values of the block-sparse Hessian, with the slot of each vertex's diagonal block and of each
    tet's 16 blocks in ``values`` (:class:`licrom.full.pcg.BlockHessian`)."""

    energy: wp.array(dtype=f64)
    grad: wp.array(dtype=vec3d)
    values: wp.array(dtype=mat33d)
    diag_slots: wp.array(dtype=wp.int32)
    slots: wp.array2d(dtype=wp.int32)


def assembly(energy: Any, grad: Any, hessian: Any) -> Any:
    """The :class:`Assembly` of the partial sums ``energy``, the gradient ``grad`` and a ``BlockHessian``'s values and slots."""
    out = Assembly()
    out.energy, out.grad = energy, grad
    out.values, out.diag_slots, out.slots = hessian.values, hessian.diag_slots, hessian.slots
    return out


_initialised = False
# warp's native library prints this at initialisation on every machine without an NVIDIA driver.
# A CPU run needs no driver, and a CUDA device asked for without one is refused by resolve_device.
_NO_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


@contextlib.contextmanager
def _native_stderr_without(text: str) -> Iterator[None]:
    """Capture what native code writes to file descriptor 2 and pass on every line but those holding ``text``."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            kept = [line for line in capture.read().decode(errors="replace").splitlines(keepends=True) if text not in line]
            if kept:
                sys.stderr.write("".join(kept))
                sys.stderr.flush()


def warp_ready() -> Any:
    """Initialise warp once (without its missing-driver warning on CPU-only machines) and return it."""
    global _initialised
    if not _initialised:
        with _native_stderr_without(_NO_DRIVER_WARNING):
            wp.init()
        _initialised = True
    return wp


KERNEL_MODULES = ("elastic", "damping", "contact", "inertia", "pcg", "validity")
"""The modules of :mod:`licrom.full` that hold warp kernels."""


def _compiled(module: Any, device: str) -> bool:
    """Whether warp's kernel cache holds ``module`` built for ``device`` (True where it cannot tell)."""
    try:
        folder = os.path.join(wp.config.kernel_cache_dir, module.get_module_identifier())
    except (AttributeError, TypeError):  # another warp: no guess, no message
        return True
    suffixes = (".o",) if device == "cpu" else (".ptx", ".cubin")
    return os.path.isdir(folder) and any(name.endswith(suffixes) for name in os.listdir(folder))


def load_kernels(device: str, say: Callable[[str], None] | None = None) -> None:
    """Load the full simulation's warp kernels on ``device``, first saying so through ``say`` when
    warp must compile them (the first run after an install or an upgrade: about a minute on two
    cores), so that a progress bar standing at 0 does not look hung."""
    warp_ready()
    modules = [wp.get_module(f"licrom.full.{name}") for name in KERNEL_MODULES]
    if say is not None and not all(_compiled(m, device) for m in modules):
        say(f"warp is compiling the full simulation's kernels for {device} (first run only, about a minute)...")
    for m in modules:
        wp.load_module(m, device=device)


def check_device_name(device: Any) -> str:
    """``device`` as an accepted name (``None`` -> ``"auto"``), without looking at the devices present.

    Raises:
        ConfigError: anything but ``None`` and the :data:`ACCEPTED_DEVICES`.
    """
    if device is None:
        return "auto"
    if not isinstance(device, str) or not re.fullmatch(r"auto|cpu|cuda|cuda:\d+", device):
        raise ConfigError(f"device must be one of {', '.join(ACCEPTED_DEVICES)} (N = 0, 1, ...) or None (auto), got {device!r}")
    return device


def resolve_device(device: Any) -> str:
    """The warp device to run on: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``.

    ``None`` or ``"auto"`` pick ``"cuda"`` when warp sees a CUDA device, else ``"cpu"``;
    an explicit name is checked against the devices present.

    Raises:
        ConfigError: a name outside :data:`ACCEPTED_DEVICES`, or a CUDA device that is not there.
    """
    device = check_device_name(device)
    if device == "cpu":
        return device
    wp = warp_ready()
    count = wp.get_cuda_device_count()
    if device == "auto":
        return "cuda" if count > 0 else "cpu"
    if count == 0:
        raise ConfigError(f"device {device!r} requested but no CUDA device is available here; accepted here: auto, cpu")
    if device != "cuda" and int(device.split(":")[1]) >= count:
        raise ConfigError(f"device {device!r} does not exist: {count} CUDA device(s) available (cuda:0..cuda:{count - 1})")
    return device

