"""A rolling body's non-rigid error frame by frame: how far the reduced body has turned beyond the full one.

    python experiments/rolling_phase.py --model MODEL --run RUN.npz [--every-tet] [--frames 30 50 75 100]

Replays the full run's scene with ``ReducedSim(model, scene=run.scene)`` at the run's own cadence, with the model's
cubature and, with ``--every-tet``, with every tet as cubature (the subspace integrated exactly). For each frame asked
for it prints:
- the frame's non-rigid error: the mass-weighted body-frame difference over the full run's own body-frame
  deformation in that frame (the per-frame terms of :func:`licrom.analysis.compare.nonrigid_error`; "-" where the full
  body is undeformed, before its first contact);
- the angle the reduced body has turned beyond the full one (each frame's best rigid fit, :func:`licrom.rigid.rigid_fit`)
  and the world axis of that rotation;
- the centres of mass apart, mm;
- the size of the reduced body's deformation over the full one's.
Then the run-level figures of :func:`licrom.analysis.compare.compare`. docs/results.md section 39 ran it on the
104k-tet ball's validation run ``sphere_20_0.2``: where the error grows with the angle about the rolling axis, the
body-frame comparison sees the contact patch at another place on the body, and the error is the spin's phase.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
from licrom import Model, ReducedSim, Trajectory
from licrom.analysis.compare import compare
from licrom.errors import LicromWarning
from licrom.learn.training.held_out import run_cadence
from licrom.rigid import body_frame_displacements, rigid_fit, rotation_angle

UNDEFORMED = 1e-6
"""A frame whose mass-weighted body-frame deformation is below this fraction of the size is undeformed (round-off of
the rigid fit and of float32 frames); its frame error is not reported."""


def rotation_axis(rotation: np.ndarray) -> np.ndarray:
    """(3,) unit axis of a rotation (zero for the identity)."""
    r = np.asarray(rotation)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    norm = np.linalg.norm(axis)
    return axis / norm if norm > 0.0 else axis


def phase_rows(full: Trajectory, reduced: Trajectory, masses: np.ndarray, frames: list[int]) -> list[dict]:
    """Per frame asked for: the frame's non-rigid error, the angle (deg) and world axis of the reduced body's rotation
    beyond the full one's, the centres of mass apart (mm) and the deformations' size ratio."""
    rest = full.rest_positions
    xf, xr = rest + full.displacements, rest + reduced.displacements
    cf, rf = rigid_fit(xf, rest, masses)
    cr, rr = rigid_fit(xr, rest, masses)
    uf = body_frame_displacements(xf, rest, masses)
    ur = body_frame_displacements(xr, rest, masses)
    undeformed = UNDEFORMED * full.mesh.size * np.sqrt(masses.sum())
    rows = []
    for f in frames:
        norm = np.sqrt(masses @ (uf[f] ** 2).sum(1))
        norm = norm if norm > undeformed else 0.0
        beyond = rr[f] @ rf[f].T
        rows.append({
            "frame": f, "t": float(full.times[f]),
            "frame_error": float(np.sqrt(masses @ ((ur[f] - uf[f]) ** 2).sum(1)) / norm) if norm > 0.0 else float("nan"),
            "turned_deg": float(np.degrees(rotation_angle(beyond))), "axis": rotation_axis(beyond).round(2).tolist(),
            "com_mm": float(1e3 * np.linalg.norm(cr[f] - cf[f])),
            "deformation_ratio": float(np.sqrt(masses @ (ur[f] ** 2).sum(1)) / norm) if norm > 0.0 else float("nan"),
        })
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, required=True, help="a trained body-frame model (.lcm)")
    ap.add_argument("--run", type=Path, required=True, help="a full run of the model's mesh (.npz)")
    ap.add_argument("--every-tet", action="store_true", help="also replay with every tet as cubature")
    ap.add_argument("--frames", type=int, nargs="+", default=None, help="frames to report (default: 4 spread over the run)")
    args = ap.parse_args()
    model, full = Model.load(args.model), Trajectory.load(args.run)
    cadence = run_cadence(full)
    if cadence is None:
        ap.error(f"{args.run}: {full.n_frames} frames over {len(full.iterations)} steps are not evenly spaced steps")
    last = full.n_frames - 1
    frames = args.frames or sorted({max(1, round(last * k / 10)) for k in (3, 5, 7.5, 10)})
    if max(frames) > last or min(frames) < 0:
        ap.error(f"--frames must lie in 0..{last}, got {frames}")
    masses = model.mesh.vertex_masses(model.default_scene.material.density)
    cubatures = {"the model's cubature": None} | ({"every tet": "full"} if args.every_tet else {})
    print(f"{args.run.name} with {args.model}: {full.n_frames} frames, {cadence[0]} steps")
    for label, cubature in cubatures.items():
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LicromWarning)  # the figures below say how far off the run is
            reduced = ReducedSim(model, scene=full.scene, cubature=cubature).run(cadence[0], record_every=cadence[1])
        c = compare(full, reduced)
        print(f"== {label} ({time.perf_counter() - start:.0f} s): non-rigid {100 * c.nonrigid_error:.1f} %, "
              f"centre of mass {100 * c.final_com_error:.2f} % of the size, estimate {100 * c.error_estimate:.1f} %")
        print("   t (s) | frame error | turned beyond the full body (deg, world axis) | centres apart (mm) | deformation ratio")
        for row in phase_rows(full, reduced, masses, frames):
            error = "-" if np.isnan(row["frame_error"]) else f"{100 * row['frame_error']:.1f} %"
            ratio = "-" if np.isnan(row["deformation_ratio"]) else f"{row['deformation_ratio']:.2f}"
            print(f"   {row['t']:.2f} | {error} | {row['turned_deg']:.2f} {row['axis']} | {row['com_mm']:.2f} | {ratio}")


if __name__ == "__main__":
    main()
