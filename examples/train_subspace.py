"""Train a LiCROM subspace on simulated trajectories and use it as a basis.

    python examples/train_subspace.py DATA_DIR [--epochs 50] [--modes 20] [--device auto]

DATA_DIR holds trajectory files of one mesh, e.g. from ``licrom generate DATA_DIR``.
Writes ``DATA_DIR/../model.lcm`` (plus its loss CSV and plot), reloads it, and shows
the basis at work: values and Jacobians at tet centroids, the exact projection of a
held-out frame and the encoder's latent for the same frame.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import licrom
import numpy as np
from licrom.learn.model import ModelConfig
from licrom.learn.training_data import TrainingData
from licrom.rigid import relative_error


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--modes", type=int, default=20)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()

    out = Path(args.out) if args.out else Path(args.data).resolve().parent / "model.lcm"
    model = licrom.train(args.data, out, licrom.TrainConfig(epochs=args.epochs, device=args.device), ModelConfig(latent_dim=args.modes))
    model = licrom.Model.load(out)  # loads without the training data
    print(model, "default scene dt =", model.default_scene.dt)

    centroids = model.mesh.centroids
    values, jacobians = model.values_and_jacobians(centroids)
    print("values", values.shape, "jacobians", jacobians.shape)

    data = TrainingData(args.data, val_fraction=model.metadata["train_config"]["val_fraction"], seed=model.metadata["train_config"]["seed"])
    frames = data.val if len(data.val) else data.train
    u = frames.full_displacements(data.rest, len(frames) // 2)
    q = model.project(u)
    q_enc = model.encode_q(model.mesh.vertices, u)
    masses = model.mesh.vertex_masses(1.0)
    residual = frames.residuals[len(frames) // 2].astype(np.float64)
    for name, qq in (("projection", q), ("encoder", q_enc)):
        rec = model.reconstruct(qq)
        print(f"{name:>10}: full error {100 * relative_error(u, rec, masses):.4f} %, "
              f"residual error {100 * relative_error(residual, residual - (u - rec), masses):.2f} %")


if __name__ == "__main__":
    main()
