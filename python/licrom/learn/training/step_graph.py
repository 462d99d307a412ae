"""The training step's forward and backward pass, captured in a CUDA graph and replayed.

On a large mesh a training step is bound by its operator calls, not by the GPU: about 590 of them at some 8 us
each, a step's 4-6 ms whatever its points (docs/results.md section 41). A CUDA graph records the kernels of one
forward and backward pass once and replays them with one call. Only that pass is captured: the points are drawn
before it (with the step's own generator) and copied into the graph's input tensors, and Adam steps after it on the
gradients it leaves, so the optimiser, its learning-rate schedule and checkpoints are those of an eager step.

The gradients live in tensors allocated once, before the first capture, and each graph zeroes them before its
backward pass accumulates into them, so that graphs of several batch sizes (an epoch's last batch may be shorter)
share one set and the optimiser always reads the gradients of the pass just replayed. They are held here and set as
the parameters' ``.grad`` before every pass: Lightning sets those to None between epochs, and a graph replayed into
tensors nobody holds would write into freed memory (measured: a validation's indices overwritten, an index assert).

Where a capture fails (an operation that cannot be recorded: a host synchronisation, or a library or driver that
does not support it), a :class:`~licrom.errors.LicromWarning` says so and every later pass runs eagerly.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from ...errors import LicromWarning

__all__ = ["WARMUP_PASSES", "StepGraphs"]

WARMUP_PASSES = 3
"""Eager passes on a side stream before a capture: they initialise the libraries' workspaces and autograd's state,
which must not be created while a graph is recorded (PyTorch's recipe for whole-network capture)."""


@dataclass
class _Captured:
    graph: torch.cuda.CUDAGraph
    inputs: tuple[torch.Tensor, ...]
    loss: torch.Tensor


class StepGraphs:
    """Forward and backward passes of ``loss_of(*inputs)`` replayed from CUDA graphs, one per set of input shapes.

    Args:
        parameters: the tensors whose gradients the pass computes (every one must require a gradient).
        loss_of: the pass's loss from its input tensors; it must launch the same kernels for inputs of the same
            shapes (no host synchronisation, no data-dependent shapes, no random numbers).
        capture: record and replay graphs (on CUDA); False runs the same pass eagerly each time, into the same
            shared gradients (what the tests on a CPU check against plain eager steps).
    """

    def __init__(self, parameters: Sequence[torch.Tensor], loss_of: Callable[..., torch.Tensor], capture: bool = True) -> None:
        self.parameters = list(parameters)
        self.loss_of = loss_of
        self.capture = capture
        self._graphs: dict[tuple, _Captured] = {}
        self._grads: list[torch.Tensor] | None = None
        self.passes = 0

    @property
    def captured(self) -> int:
        """Graphs captured so far (one per set of input shapes seen)."""
        return len(self._graphs)

    def loss(self, *inputs: torch.Tensor) -> torch.Tensor:
        """Replay the pass for ``inputs``: the loss (a tensor the next replay overwrites) and each parameter's
        ``.grad``, as ``loss_of(*inputs).backward()`` on zeroed gradients would leave them."""
        self.passes += 1
        self._set_grads()
        if not self.capture:
            return self._pass(tuple(inputs))
        key = tuple((t.shape, t.dtype) for t in inputs)
        captured = self._graphs.get(key)
        if captured is None:
            try:
                captured = self._graphs[key] = self._capture(inputs)
            except RuntimeError as exc:  # torch's CUDA errors (AcceleratorError among them) are RuntimeErrors
                warnings.warn(f"recording the training step in a CUDA graph failed ({str(exc).splitlines()[0]}); the steps "
                              "run eagerly (TrainConfig(cuda_graph=False) asks for that directly)", LicromWarning, stacklevel=2)
                self.capture = False
                torch.cuda.synchronize()
                return self._pass(tuple(inputs))
        for static, value in zip(captured.inputs, inputs):
            static.copy_(value)
        captured.graph.replay()
        return captured.loss

    def _pass(self, inputs: tuple[torch.Tensor, ...]) -> torch.Tensor:
        for p in self.parameters:
            p.grad.zero_()
        loss = self.loss_of(*inputs)
        loss.backward()
        return loss

    def _set_grads(self) -> None:
        if self._grads is None:
            self._grads = [torch.zeros_like(p) for p in self.parameters]
        for p, g in zip(self.parameters, self._grads):
            p.grad = g

    def _capture(self, inputs: Sequence[torch.Tensor]) -> _Captured:
        static = tuple(t.detach().clone() for t in inputs)
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(WARMUP_PASSES):
                self._pass(static)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            loss = self._pass(static)
        # Detached: the replays write into its storage, and holding its autograd graph would keep the parameters'
        # gradient accumulators of this capture's stream alive into the next capture (torch's stream-mismatch warning).
        return _Captured(graph, static, loss.detach())
