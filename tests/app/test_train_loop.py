"""The parts every training loop shares: schedule, held-back scenes, steps and their log."""

from __future__ import annotations

import pytest
import torch

from panogrf.app.errors import UserError
from panogrf.app.train.loop import Steps, held_back, init_from, lr_at, save_weights


def test_cosine_schedule_runs_from_lr_to_one_percent():
    assert lr_at(0, 100, 1e-3) == pytest.approx(1e-3)
    assert lr_at(50, 100, 1e-3) == pytest.approx(1e-3 * (0.01 + 0.99 * 0.5))
    assert lr_at(100, 100, 1e-3) == pytest.approx(1e-5)


def test_held_back_scenes_are_the_last_and_never_all():
    train, val = held_back(100, 24)
    assert val.tolist() == list(range(80, 100))
    assert train.tolist() == list(range(80))  # at most a fifth
    train, val = held_back(3, 24)
    assert train.tolist() == [0, 1] and val.tolist() == [2]


def test_steps_optimise_schedule_and_log_running_means():
    torch.manual_seed(0)
    net = torch.nn.Linear(3, 1)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    lines: list[str] = []
    steps = Steps(opt, 5, 0.1, 2, lines.append, clip=tuple(net.parameters()))
    x, y = torch.randn(16, 3), torch.randn(16, 1)
    losses = []
    for step in steps:
        assert opt.param_groups[0]["lr"] == pytest.approx(lr_at(step, 5, 0.1))
        loss = ((net(x) - y) ** 2).mean()
        losses.append(loss.item())
        steps.update(loss)
    assert losses[-1] < losses[0]  # it optimises
    # A line every second step and one at the end, each the mean since the last line.
    assert [line.split()[1] for line in lines] == ["2", "4", "5"]
    assert f"loss {(losses[0] + losses[1]) / 2:.4f}" in lines[0]
    assert f"loss {losses[4]:.4f}" in lines[2]


def test_steps_average_several_terms_for_the_caller_to_describe():
    net = torch.nn.Linear(1, 1)
    opt = torch.optim.SGD(net.parameters(), lr=0.0)
    lines: list[str] = []
    steps = Steps(opt, 2, 0.0, 2, lines.append, describe=lambda m: f"a {m[0]:.1f} b {m[1]:.1f}")
    for step in steps:
        steps.update(net.weight.sum() * 0, torch.tensor([float(step), 10.0 * step]))
    assert "a 1.5 b 15.0" in lines[0]


def test_init_from_refuses_weights_of_another_network(tmp_path):
    save_weights(torch.nn.Linear(3, 2), tmp_path / "a.safetensors", {"note": "x"})
    net = torch.nn.Linear(3, 2)
    init_from(net, tmp_path / "a.safetensors", lambda _: None)
    with pytest.raises(UserError, match="does not fit"):
        init_from(torch.nn.Sequential(torch.nn.Linear(3, 2)), tmp_path / "a.safetensors", print)
    with pytest.raises(UserError, match="does not fit"):  # another shape: another preset's
        init_from(torch.nn.Linear(4, 2), tmp_path / "a.safetensors", print)
    (tmp_path / "junk.safetensors").write_text("junk")
    for bad in (tmp_path / "junk.safetensors", tmp_path):
        with pytest.raises(UserError, match="--init"):
            init_from(net, bad, print)


def test_held_back_refuses_a_dataset_with_nothing_left_to_train_on():
    with pytest.raises(UserError, match="none to train on"):
        held_back(1, 4)
    train, val = held_back(2, 4)
    assert train.tolist() == [0] and val.tolist() == [1]
