"""Training of the learned subspace with PyTorch Lightning.

``licrom.train(data, "model.lcm")`` loads the trajectories, splits them by
trajectory, removes each frame's rigid part (body frame, the default) and its
affine part, and fits the PointNet encoder and the neural field W(X) (Adam,
exponentially decaying learning rate, float32). Each step draws
``batch_frames`` frames and ``points_per_frame`` points per frame, uniformly in
volume (random points in random tets, the displacement interpolated linearly),
so the loss estimates the mass-weighted L2 error of the continuous field. The
sampling runs on the training device from a generator seeded by (seed, step),
so a run is the same twice on the CPU and a resumed run draws the same points.

Two objectives (``TrainConfig.objective``):

* ``"pod"`` (default): the field is regressed onto the r mass-orthonormal POD
  modes of the training residuals (sampled at the same random points), and the
  encoder onto each frame's POD coordinates. The field stays continuous and
  differentiable in X, so the model still transfers to other meshes, and its
  span approaches POD(r) of the training frames, the best r-dimensional
  subspace for them: this is how the learned subspace reaches the POD bound
  (:func:`subspace_report`). Adam brings the field's hidden layers close, then the
  output layer (linear in its weights) is solved exactly by mass-weighted least
  squares at the vertices. On the demo data (r = 8, body frame, held-out scenes)
  this left 1.01x the projection error of POD(8) after 60 epochs and 1.02x after
  30, where the autoencoder left 1.9x (same field, 60 epochs): a supervised fit
  to a known target converges in CPU minutes, the autoencoder's search does not.
* ``"autoencoder"``: LiCROM's joint encoder/field training (plus the optional
  projection loss), kept for comparison.

Every epoch the held-out trajectories are evaluated exactly: the relative
mass-weighted L2 error of the projection onto ``[affine | W]`` at all vertices,
and of the encoder's reconstruction. Written next to the model file
``model.lcm``: ``model.losses.csv`` (one row per epoch), ``model.losses.png``,
and Lightning checkpoints in ``model.checkpoints/`` (``last.ckpt`` for resume).

Several GPUs train through Lightning's DDP (one process per GPU). Lightning
starts the other processes by re-running the command that called ``train``, so
call it from a script or the ``licrom train`` command, once per process.

r is chosen from the data by default (``ModelConfig.latent_dim="auto"``): the smallest r whose
leave-runs-out POD projection error meets ``TrainConfig.rank_tolerance`` (:mod:`.rank`), then
raised where replays of training runs on POD(r) miss the targets (:mod:`.dynamics`).
Training ends by fitting the model's cubature and by running the model as a user runs it,
``ReducedSim(model, scene=scene)``, on each held-out run, against that run
(:func:`check_held_out`, ``model.metadata["held_out"]``; an ``AccuracyWarning`` names
every held-out run that misses a target: non-rigid error at or above 10 %, centre of
mass at or above 2 % of the size, or stick/slip wrong).

Where things live: :mod:`.config` (:class:`TrainConfig`), :mod:`.rank` (:func:`choose_rank`), :mod:`.dynamics` (:func:`check_dynamics`),
:mod:`.held_out` (:func:`check_held_out`), :mod:`.sampling` (points drawn uniformly
in volume), :mod:`.objectives` (the POD objective), :mod:`.evaluation` (:func:`evaluate`,
:func:`subspace_report`), :mod:`.lightning` (the Lightning module), :mod:`.checkpoints` (weights-only,
atomic checkpoints resumed only into their own run) and :mod:`.run` (:func:`train`).
"""

from .config import OBJECTIVES, TrainConfig, output_paths
from .dynamics import DynamicsCheck, check_dynamics
from .evaluation import evaluate, subspace_report
from .held_out import check_held_out
from .rank import RankChoice, choose_rank
from .run import plot_losses, train

__all__ = ["OBJECTIVES", "DynamicsCheck", "RankChoice", "TrainConfig", "check_dynamics", "check_held_out", "choose_rank", "evaluate", "output_paths", "plot_losses", "subspace_report", "train"]
