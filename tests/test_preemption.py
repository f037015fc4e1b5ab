"""A preempted submitit job (submitit's USR2 while a model trains) checkpoints at the end of the step it is in and
hands the signal to submitit's handler there (simeval.runtime.preemption). Here a handler that stands in for
submitit's records its call and raises SystemExit, as submitit's requeue does; the signal is sent from inside a
step (the trainers' metric callbacks run in the step), so the tests know which step it came in."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest
import torch
from omegaconf import OmegaConf

from simeval.cli import exit_cleanly_on_user_error
from simeval.episodes.dataset import WindowSpec
from simeval.models.diffusion_policy import DiffusionPolicy, TrainSettings, train_policy
from simeval.measures.dynamics_diversity.run import Evaluation, Execution, Training, fit_and_evaluate
from simeval.measures.generalization.data import PolicyDataset
from simeval.runtime.preemption import PreemptionPoint, preemption_signal, requeue_deaf_to_sigterm
from simeval.measures.dynamics_diversity.controls.synthetic import make_group
from simeval.models.world_model_training import TrainConfig
from simeval.models.world_model import WorldModelConfig
from helpers import policy_config, square_episode

REQUEUE_EXIT = 144  # what submitit's local executor exits with to be requeued (any code works here)


@pytest.fixture
def submitit_handler(monkeypatch):
    """A Python handler on USR2 that records each call and exits like submitit's requeue; SUBMITIT_EXECUTOR set as
    in a submitit job. The previous handler is put back afterwards."""
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "local")
    monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL", raising=False)
    calls = []

    def requeue(signum, frame):
        calls.append(signum)
        raise SystemExit(REQUEUE_EXIT)

    old = signal.signal(signal.SIGUSR2, requeue)
    old_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield calls, requeue
    signal.signal(signal.SIGUSR2, old)
    torch.set_num_threads(old_threads)


def _preempt_at(step_to_signal: int):
    def log(metrics, step):
        if step == step_to_signal:
            os.kill(os.getpid(), signal.SIGUSR2)
    return log


def _fit_world_model(checkpoint_dir, log_metrics=None):
    cfg = WorldModelConfig(image_size=16, deter=16, hidden=16, stoch=2, classes=4, cnn_depth=4, minres=4,
                           mlp_layers=1, mlp_units=8)
    return fit_and_evaluate(make_group("shared", 2, 4, 12, 16), 4,
                            Training(cfg, TrainConfig(epochs=3, batch_size=2, lr=1e-3, checkpoint_every=1000),
                                     WindowSpec(length=5, stride=2)),
                            Evaluation(episodes=(0, 4), heldout_episodes=None),
                            Execution(checkpoint_dir=checkpoint_dir, progress=False, log_metrics=log_metrics,
                                      device="cpu"))


def test_the_world_model_saves_the_step_it_was_preempted_in_then_calls_submitits_handler(tmp_path, submitit_handler):
    calls, requeue = submitit_handler
    with pytest.raises(SystemExit) as stop:
        _fit_world_model(tmp_path / "ck", _preempt_at(3))
    assert stop.value.code == REQUEUE_EXIT and calls == [signal.SIGUSR2]  # submitit's handler ran, once
    assert signal.getsignal(signal.SIGUSR2) is requeue  # and is the handler again after the loop
    [path] = (tmp_path / "ck").glob("world_model-*.pt")
    ck = torch.load(path, weights_only=False)
    assert ck["step"] == 3 and not ck["finished"]  # not the last periodic checkpoint (none: every 1000 steps)

    resumed = _fit_world_model(tmp_path / "ck")  # the requeued job: same command, same checkpoint
    whole = _fit_world_model(tmp_path / "whole")  # never preempted
    assert resumed["train"]["steps"] == whole["train"]["steps"] > 3
    assert resumed["eval"]["image_error"] == whole["eval"]["image_error"]  # the same steps were taken


def _train_policy(ckpt_dir, log_fn=None):
    ds = PolicyDataset([square_episode()], "joint", ["top"], [32, 32], 8, 2)
    fresh = DiffusionPolicy(policy_config(), ds.state_dim, ds.action_dim, ds.stats(), seed=0)
    return train_policy(fresh, ds, TrainSettings(train_steps=8, batch_size=8, warmup_steps=2, checkpoint_every=100,
                                                 log_every=1), ckpt_dir, log_fn=log_fn, device="cpu")


@pytest.mark.parametrize("at", [3, 8])  # mid-run, and in the last step (the final checkpoint then holds all 8)
def test_the_policy_saves_the_step_it_was_preempted_in_then_calls_submitits_handler(tmp_path, submitit_handler, at):
    calls, _ = submitit_handler
    with pytest.raises(SystemExit) as stop:
        _train_policy(tmp_path / "ck", _preempt_at(at))
    assert stop.value.code == REQUEUE_EXIT and calls == [signal.SIGUSR2]
    assert torch.load(tmp_path / "ck" / "last.ckpt", weights_only=False)["step"] == at

    resumed, summary = _train_policy(tmp_path / "ck")
    whole, _ = _train_policy(tmp_path / "whole")
    assert summary["steps"] == 8
    for k, v in whole.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[k], v, rtol=0, atol=0, msg=k)


def test_outside_a_submitit_job_the_handler_runs_at_once(monkeypatch, submitit_handler):
    """No SUBMITIT_EXECUTOR: the handler is left alone and runs inside the step, as it always did."""
    calls, requeue = submitit_handler
    monkeypatch.delenv("SUBMITIT_EXECUTOR")
    ran_on = []
    with pytest.raises(SystemExit), PreemptionPoint() as point:
        os.kill(os.getpid(), signal.SIGUSR2)
        ran_on.append("after the signal")
    assert calls == [signal.SIGUSR2] and ran_on == [] and not point.pending


def test_a_signal_in_the_loops_last_moment_is_delivered_when_the_block_ends(submitit_handler):
    calls, requeue = submitit_handler
    with pytest.raises(SystemExit):
        with PreemptionPoint() as point:
            os.kill(os.getpid(), signal.SIGUSR2)
            assert point.pending and calls == []  # recorded, not yet handled
    assert calls == [signal.SIGUSR2] and signal.getsignal(signal.SIGUSR2) is requeue


# A child that gets SIGTERM before it exits, as `scontrol requeue` can: SLURM's requeue signals every process of
# the job. check_call raises CalledProcessError for it, as submitit's requeue does.
_CHILD_TERMINATED_WHILE_RUNNING = [sys.executable, "-c",
                                   "import os, signal, time; os.kill(os.getpid(), signal.SIGTERM); time.sleep(0.2)"]


@pytest.fixture
def submitit_slurm_handlers(monkeypatch):
    """Stand-ins for submitit's two handlers in a SLURM job: SIGTERM bypassed by a Python handler (recording what
    reaches this process) and a USR2 requeue whose child gets SIGTERM while it runs, then exits like submitit's
    requeue. Yields (bypass, requeue, signals bypassed, signals requeued on); both old handlers are put back."""
    monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL", raising=False)
    bypassed, requeued = [], []

    def submitits_bypass(signum, frame):
        bypassed.append(signum)

    def submitits_requeue(signum, frame):
        requeued.append(signum)
        subprocess.check_call(_CHILD_TERMINATED_WHILE_RUNNING, timeout=60)
        raise SystemExit(REQUEUE_EXIT)

    old_term = signal.signal(signal.SIGTERM, submitits_bypass)
    old_usr2 = signal.signal(signal.SIGUSR2, submitits_requeue)
    yield submitits_bypass, submitits_requeue, bypassed, requeued
    signal.signal(signal.SIGTERM, old_term)
    signal.signal(signal.SIGUSR2, old_usr2)


def test_the_requeue_command_outlives_the_sigterm_the_requeue_sends_the_job(monkeypatch, submitit_slurm_handlers):
    """submitit's handler runs `scontrol requeue` in a child and SLURM's requeue sends SIGTERM to the whole job, that
    child included; submitit ignores SIGTERM only in its own process (a Python handler, not inherited). A CI run's
    job died of it: CalledProcessError out of the handler, the job ended with that error although requeued. Delivered
    by the PreemptionPoint, the child is deaf to SIGTERM and the handler gets as far as its exit; submitit's SIGTERM
    handler is back afterwards. Called as submitit calls it, the same handler fails (so this test can tell)."""
    submitits_bypass, submitits_requeue, bypassed, _ = submitit_slurm_handlers
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "slurm")
    with pytest.raises(subprocess.CalledProcessError) as died:
        submitits_requeue(signal.SIGUSR2, None)
    assert died.value.returncode == -signal.SIGTERM

    with pytest.raises(SystemExit) as exited, PreemptionPoint() as point:
        os.kill(os.getpid(), signal.SIGUSR2)
        point.deliver(step=3)
    assert exited.value.code == REQUEUE_EXIT
    assert signal.getsignal(signal.SIGTERM) is submitits_bypass and signal.getsignal(signal.SIGUSR2) is submitits_requeue
    assert bypassed == []  # the child's SIGTERM was its own; none reached this process


def test_outside_a_training_loop_the_job_start_wrapping_makes_submitits_requeue_deaf_to_sigterm(
        monkeypatch, submitit_slurm_handlers):
    """A signal outside any training loop (loading data, evaluating) runs submitit's handler at once. Every
    entrypoint's job calls requeue_deaf_to_sigterm first (through exit_cleanly_on_user_error), which wraps that
    handler once: the requeue's child outlives its SIGTERM there too. Outside a submitit job nothing is wrapped."""
    submitits_bypass, submitits_requeue, _, seen_signals = submitit_slurm_handlers
    monkeypatch.delenv("SUBMITIT_EXECUTOR", raising=False)
    requeue_deaf_to_sigterm()
    assert signal.getsignal(signal.SIGUSR2) is submitits_requeue

    monkeypatch.setenv("SUBMITIT_EXECUTOR", "slurm")
    requeue_deaf_to_sigterm()
    wrapped = signal.getsignal(signal.SIGUSR2)
    requeue_deaf_to_sigterm()  # a second call (a second entrypoint in one process) does not wrap it again
    assert wrapped is not submitits_requeue and signal.getsignal(signal.SIGUSR2) is wrapped
    with pytest.raises(SystemExit) as exited:
        os.kill(os.getpid(), signal.SIGUSR2)
    assert exited.value.code == REQUEUE_EXIT and seen_signals == [signal.SIGUSR2]
    assert signal.getsignal(signal.SIGTERM) is submitits_bypass

    signal.signal(signal.SIGUSR2, submitits_requeue)

    @exit_cleanly_on_user_error
    def entrypoint(cfg):
        return signal.getsignal(signal.SIGUSR2)

    assert getattr(entrypoint(OmegaConf.create({})), "deaf_to_sigterm", False)


def test_the_signal_name_is_read_as_submitit_reads_it(monkeypatch):
    monkeypatch.setenv("SUBMITIT_PREEMPT_SIGNAL", "USR1")
    assert preemption_signal() == signal.SIGUSR1
    monkeypatch.setenv("SUBMITIT_PREEMPT_SIGNAL", "TERM")
    assert preemption_signal() == signal.SIGTERM
    monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL")
    assert preemption_signal() == signal.SIGUSR2


def test_the_shared_loop_checkpoints_on_its_cadence_and_at_a_preemption_then_hands_over(submitit_handler):
    """simeval.runtime.trainer.CheckpointedSteps, both models' loop: a checkpoint every 3 steps (not at a step where
    periodic=False), and at the step a preemption signal came in, before submitit's handler runs."""
    from simeval.runtime.trainer import CheckpointedSteps

    calls, _ = submitit_handler
    saved: list[int] = []
    step = 0
    with CheckpointedSteps(lambda: saved.append(step), every=3) as loop:
        for step in range(1, 8):
            loop.step_done(step, periodic=step < 6)
    assert saved == [3] and calls == []  # 6 is not periodic here; no signal came

    saved.clear()
    with pytest.raises(SystemExit) as stop, CheckpointedSteps(lambda: saved.append(step), every=100) as loop:
        for step in range(1, 8):
            if step == 5:
                os.kill(os.getpid(), signal.SIGUSR2)  # recorded only: the step runs to its end
            loop.step_done(step)
    assert stop.value.code == REQUEUE_EXIT and saved == [5] and calls == [signal.SIGUSR2]


def test_the_one_training_loop_numbers_steps_from_the_resume_point_and_saves_on_its_cadence(submitit_handler):
    """simeval.runtime.trainer.run_steps, both models' loop: a run resumed at step 3 with 5 batches left takes steps
    3..7 (take_step sees the steps before it, after_step the steps after), saves at 4 and 6 (every 2) but not at
    the last step 8 (last_step: the final save follows at once), then the final save at 8; a signal during the step
    that ends at 5 saves there and hands over."""
    from simeval.runtime.trainer import run_steps

    calls, _ = submitit_handler
    taken, after, saved, final = [], [], [], []

    def take(batch, before):
        taken.append((batch, before))
        return {"loss": float(before)}

    end = run_steps("abcde", take, saved.append, step=3, checkpoint_every=2, last_step=8,
                    after_step=lambda s, m, seconds: after.append((s, m["loss"], seconds >= 0)),
                    final_save=final.append)
    assert end == 8 and taken == [("a", 3), ("b", 4), ("c", 5), ("d", 6), ("e", 7)]
    assert after == [(4, 3.0, True), (5, 4.0, True), (6, 5.0, True), (7, 6.0, True), (8, 7.0, True)]
    assert saved == [4, 6] and final == [8] and calls == []

    saved.clear()

    def take_and_signal(batch, before):
        if before == 4:
            os.kill(os.getpid(), signal.SIGUSR2)
        return {}

    with pytest.raises(SystemExit) as stop:
        run_steps([None] * 5, take_and_signal, saved.append, step=0, checkpoint_every=100)
    assert stop.value.code == REQUEUE_EXIT and saved == [5] and calls == [signal.SIGUSR2]


def test_a_checkpoint_made_with_other_settings_names_the_keys_that_differ(tmp_path):
    from simeval.errors import UserError
    from simeval.runtime.trainer import refuse_other_settings, settings_difference

    stored = {"lr": 1e-3, "model": {"width": 32, "depth": 2}, "data": "a"}
    assert settings_difference(stored, {"lr": 1e-3, "model": {"width": 64, "depth": 2}, "seed": 0}) == [
        "data", "model.width", "seed"]
    assert settings_difference(stored, dict(stored)) == []
    refuse_other_settings(tmp_path / "last.ckpt", stored, dict(stored), "run folder")  # the same: resumes
    with pytest.raises(UserError, match=r"last.ckpt: made with other settings or data \(lr\); delete it or use "
                                        r"another run folder"):
        refuse_other_settings(tmp_path / "last.ckpt", stored, {**stored, "lr": 1e-4}, "run folder")
