"""The training step's pass through StepGraphs: the same gradients and the same training as eager steps.

Capture itself needs a GPU (``benches/training_epoch_bench.py --cuda-graph both`` trains with replayed and with eager
steps there and compares the weights: the same to the bit, docs/results.md section 44); on this CPU StepGraphs runs its
pass without capture, which checks the rest of the path: the gradients it holds, zeroes and sets, and the Lightning
hooks that leave them to it.
"""

import contextlib

import numpy as np
import pytest
import torch
from licrom import ConfigError, LicromWarning
from licrom.learn.model import ModelConfig
from licrom.learn.training import TrainConfig, lightning, train
from licrom.learn.training.step_graph import StepGraphs
from licrom.learn.training_data import make_synthetic_trajectories


def test_pass_leaves_the_gradients_of_a_fresh_backward():
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(3, 8), torch.nn.ELU(), torch.nn.Linear(8, 2))
    params = list(net.parameters())
    graphs = StepGraphs(params, lambda x, y: torch.mean((net(x) - y) ** 2), capture=False)
    for batch in (5, 5, 3):  # the gradients of one pass must not leak into the next
        x, y = torch.randn(batch, 3), torch.randn(batch, 2)
        loss = graphs.loss(x, y)
        shared = [p.grad.clone() for p in params]
        net.zero_grad(set_to_none=True)
        expected = torch.mean((net(x) - y) ** 2)
        expected.backward()
        assert torch.equal(loss, expected)
        for got, p in zip(shared, params):
            assert torch.equal(got, p.grad)
        net.zero_grad(set_to_none=True)  # as Lightning does between epochs
    graphs.loss(torch.randn(4, 3), torch.randn(4, 2))
    grads = [p.grad for p in params]
    net.zero_grad(set_to_none=True)
    graphs.loss(torch.randn(4, 3), torch.randn(4, 2))
    assert all(p.grad is g for p, g in zip(params, grads))  # every pass sets the tensors it writes (a graph's own)
    assert graphs.passes == 5 and graphs.captured == 0


def test_a_failed_capture_warns_and_runs_the_pass_eagerly(monkeypatch):
    torch.manual_seed(1)
    net = torch.nn.Linear(3, 2)
    graphs = StepGraphs(list(net.parameters()), lambda x: net(x).square().mean())

    def fails(inputs):
        raise RuntimeError("CUDA error: operation not permitted when stream is capturing\nmore")

    monkeypatch.setattr(graphs, "_capture", fails)
    monkeypatch.setattr(torch.cuda, "synchronize", lambda: None)  # no CUDA here
    x = torch.randn(4, 3)
    with pytest.warns(LicromWarning, match="operation not permitted.*run eagerly"):
        loss = graphs.loss(x)
    assert not graphs.capture and graphs.captured == 0
    assert torch.equal(loss, net(x).square().mean())
    grad = net.weight.grad.clone()
    net.zero_grad(set_to_none=True)
    net(x).square().mean().backward()
    assert torch.equal(grad, net.weight.grad)


class _RecordedGraph:
    """Stands in for ``torch.cuda.CUDAGraph`` on the CPU: the captured block runs once, replays do nothing."""

    def replay(self):
        pass


class _Stream:
    def wait_stream(self, other):
        pass


def test_a_captured_loss_holds_no_autograd_graph(monkeypatch):
    # A loss kept with its autograd graph keeps the parameters' gradient accumulators of one capture's stream alive
    # into the next capture, which torch warns about (seen on an H200 when an epoch's shorter last batch is captured).
    monkeypatch.setattr(torch.cuda, "Stream", _Stream)
    monkeypatch.setattr(torch.cuda, "current_stream", _Stream)
    monkeypatch.setattr(torch.cuda, "stream", lambda stream: contextlib.nullcontext())
    monkeypatch.setattr(torch.cuda, "CUDAGraph", _RecordedGraph)
    monkeypatch.setattr(torch.cuda, "graph", lambda graph: contextlib.nullcontext())
    torch.manual_seed(2)
    net = torch.nn.Linear(3, 2)
    graphs = StepGraphs(list(net.parameters()), lambda x: net(x).square().mean())
    x = torch.randn(4, 3)
    loss = graphs.loss(x)
    assert graphs.captured == 1 and graphs.capture
    assert loss.grad_fn is None and not loss.requires_grad
    assert torch.equal(loss, net(x).square().mean().detach())


def test_training_through_step_graphs_matches_eager_training(coarse_box, monkeypatch):
    trajs = make_synthetic_trajectories(coarse_box, count=4, frames=10, seed=3, modes=3, rotation=True)
    # 7 frames a batch: the epoch's last batch is shorter, as a second graph would be
    cfg = TrainConfig(epochs=3, batch_frames=7, points_per_frame=128, encoder_points=64, val_points=64, progress=False,
                      extension=0.0, device="cpu", cubature_points=20, cubature_candidates=64)
    eager = train(trajs, None, cfg, ModelConfig(latent_dim=3))
    monkeypatch.setattr(lightning, "graph_steps", lambda module: True)
    through = train(trajs, None, cfg, ModelConfig(latent_dim=3))
    assert eager.metadata["cuda_graphs"]["passes"] == 0
    frames = through.metadata["data"]["train_frames"]
    assert frames % 7 and through.metadata["cuda_graphs"]["passes"] == 3 * -(-frames // 7)  # every step of 3 epochs
    for a, b in zip(eager.net.parameters(), through.net.parameters()):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())


def test_cuda_graph_must_be_a_bool():
    with pytest.raises(ConfigError, match="cuda_graph"):
        TrainConfig(cuda_graph="yes")
