"""Learned continuous subspaces (LiCROM): PointNet encoder, neural field W(X), the model file.

A trained :class:`Model` is a *basis* for the reduced simulation: the displacement
of any material point ``X`` of the rest shape is ``u(X) = B(X) q`` with

    B(X) = [A(X) | W(X)]    (3 x (12 + r)),

where ``A`` holds the 12 affine modes and ``W`` the ``r`` learned modes. The
column order of the affine modes is fixed: for ``c`` in ``0..8`` mode ``c`` is
``X_j e_i`` with ``(i, j) = divmod(c, 3)`` (entry ``F_ij`` of a linear map),
then modes 9, 10, 11 are the translations ``e_0, e_1, e_2``.

The learned modes are the network's field after two exact linear changes made
once at the end of training (they do not change the span of ``[A | W]``):

* the part of each learned column that the affine modes explain on the rest
  mesh is removed (``W' = W_net - A C``), so the learned modes are
  mass-orthogonal to the affine ones;
* the columns are rotated and scaled (``W = W' T``) to be mass-orthogonal with
  ``W^T M W = m_total I`` and ordered by the variance they carry over the
  training frames (mode 0 first). A latent coordinate is then the mass-weighted
  RMS displacement, in m, that its mode contributes.

This keeps the reduced mass matrix ``M_r = B^T M B`` well conditioned.

A model lives in one of two frames (:attr:`Model.frame`):

* ``"world"`` (LiCROM as published): the modes are world-frame displacement
  fields and the basis is ``[A | W]`` as above;
* ``"body"`` (the default for new models): each training frame's rigid part
  (centre of mass and polar rotation) was removed first, so ``W`` spans the
  non-rigid deformation seen in the body frame. :meth:`Model.values` and
  :meth:`Model.jacobians` then return the ``r`` learned modes only; the rigid
  motion and the symmetric affine modes are added by
  :class:`licrom.subspace.body_basis.BodyFrameBasis`, which the reduced simulation of a
  body-frame model uses. The learned modes are still mass-orthogonal to all 12
  affine modes, hence to the 6 rigid ones.

Torch is needed to evaluate a model; the file itself is a plain ``.npz`` with a
JSON header (no pickle) and loads without the training data.

Where things live: :mod:`.config` (:class:`ModelConfig`), :mod:`.networks` (the field and the
encoder), :mod:`.trained` (:class:`Model`: evaluation, projection, the file format) and
:mod:`.finalize` (the exact post-processing at the end of training).
"""

from .config import ModelConfig
from .networks import LicromNet, NeuralField, PointNetEncoder
from .trained import MODEL_FORMAT_VERSION, Model

__all__ = [
    "MODEL_FORMAT_VERSION",
    "LicromNet",
    "Model",
    "ModelConfig",
    "NeuralField",
    "PointNetEncoder",
]
