"""Bring your own mesh: from a surface (.obj) to a reduced run with pictures, with the command line only.

Runs the command sequence of docs/guide/own-mesh.md and prints the wall time of each command:

    licrom mesh potato.obj -o potato.msh --edge-length 0.2 --epsilon 0.01
    licrom scene potato.toml
    licrom generate potato-data --scene potato.toml
    licrom train potato-data -o potato.lcm -r 8 --epochs 20
    licrom compare potato.lcm --scene potato.toml --out potato-compare

The surface is a lumpy, potato-like closed triangle surface made here (``--surface`` takes a
file of your own instead), about 12 cm long. ``--small`` makes everything tiny (CI).

    python examples/own_mesh.py [--work licrom-out/own-mesh] [--surface my.obj] [--small]
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SCENE = """\
# My object dropped onto inclines: trained on 2 slopes x 3 friction coefficients,
# compared on two held-out scenes at 20 deg (tan 20 deg = 0.36): mu 0.25 slides, mu 0.55 sticks.
version = 1
name = "potato"
description = "a potato dropped onto inclines"

[object]
mesh = "potato.msh"                 # the tet mesh made by `licrom mesh`, relative to this file

[material]
youngs_modulus = 1.0e5              # Pa
poisson_ratio = 0.3
density = 1000.0                    # kg/m^3

[time]
dt = 0.01                           # s
steps = {steps}
record_every = 2                    # every other step is a training frame

[[planes]]
friction = 0.5                      # the sweep sets the slope and the friction of each run

[sweep]
frictions = [0.1, 0.4, 0.7]
slopes = [10.0, 30.0]               # deg

[[initial]]
drop_height = 0.01                  # m above the plane
rotation = [0.1, 0.2, 0.0]          # rad

[[held_out]]
slope = 20.0
friction = 0.25

[[held_out]]
slope = 20.0
friction = 0.55
"""


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere triangles, outward facing."""
    t = (1 + 5**0.5) / 2
    corners = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
               (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
             (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    points = [np.array(p, dtype=float) / np.linalg.norm(p) for p in corners]
    for _ in range(subdivisions):
        middle: dict[tuple[int, int], int] = {}
        refined = []
        for face in faces:
            mids = []
            for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
                key = (min(a, b), max(a, b))
                if key not in middle:
                    m = points[a] + points[b]
                    points.append(m / np.linalg.norm(m))
                    middle[key] = len(points) - 1
                mids.append(middle[key])
            a, b, c = face
            ab, bc, ca = mids
            refined += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = refined
    return np.array(points), np.array(faces)


def potato(path: Path, seed: int = 3) -> None:
    """Write a lumpy closed surface: an ellipsoid (12 x 8 x 6 cm) with a few smooth bumps and dents, as .obj."""
    v, f = icosphere(3)
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((6, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    amplitude = rng.uniform(-0.12, 0.18, len(centres))
    radius = 1.0 + (amplitude * np.exp(-((v @ centres.T - 1.0) ** 2) / 0.08)).sum(axis=1)
    x = v * radius[:, None] * np.array([0.06, 0.04, 0.03])
    lines = [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in x] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path.write_text("# a potato made by examples/own_mesh.py\n" + "\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("licrom-out/own-mesh"), help="Folder for every file made.")
    parser.add_argument("--surface", type=Path, default=None, help="Your own closed surface (.obj, .stl, .ply, .off) instead of the potato.")
    parser.add_argument("--small", action="store_true", help="Tiny run (20 steps, 2 epochs): checks that the commands work.")
    args = parser.parse_args()

    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    surface = work / "potato.obj"
    if args.surface is None:
        potato(surface)
    else:
        surface = args.surface.resolve()
    steps, epochs = (20, 2) if args.small else (100, 20)
    (work / "potato.toml").write_text(SCENE.format(steps=steps))

    commands = [
        f"licrom mesh {shlex.quote(str(surface))} -o potato.msh --edge-length 0.2 --epsilon 0.01",
        "licrom scene potato.toml",
        "licrom generate potato-data --scene potato.toml -q",
        f"licrom train potato-data -o potato.lcm -r 8 --epochs {epochs} -q",
        "licrom compare potato.lcm --scene potato.toml --out potato-compare -q" + (" --cubature 50" if args.small else ""),
    ]
    times = []
    for command in commands:
        print(f"\n$ {command}", flush=True)
        start = time.perf_counter()
        argv = shlex.split(command)
        subprocess.run([sys.executable, "-m", "licrom.cli", *argv[1:]], cwd=work, check=True)
        times.append(time.perf_counter() - start)
    print("\n| command | wall time |\n|---|---|")
    for command, seconds in zip(commands, times):
        print(f"| `{command}` | {seconds:.1f} s |")
    print(f"| total | {sum(times):.1f} s |")
    print(f"\noutputs in {work}: " + ", ".join(sorted(p.name for p in work.iterdir())))


if __name__ == "__main__":
    main()
