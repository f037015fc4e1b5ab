"""The one closed-loop rollout of simeval: a policy in a suite (simeval.sim.rollout.rollout_policy) and a trained
Diffusion Policy in any pipeline's environment (simeval.measures.generalization.rollouts.rollout_task) both step
through act_until_done. No simulator is imported here: any Gymnasium-style environment will do."""

from __future__ import annotations

from collections.abc import Callable


def act_until_done(env, act: Callable, obs: dict, on_step: Callable[[dict, dict], None] | None = None) -> dict:
    """Step `env` from observation `obs` with act(obs) until the episode ends (terminated, truncated) or act gives
    None (the policy gives up); on_step(obs, info) after each step. {steps, gave_up, success, progress, info}:
    progress None where the environment reports none."""
    steps, gave_up, info = 0, False, {"success": False, "progress": None}
    while True:
        action = act(obs)
        if action is None:
            gave_up = True
            break
        obs, _, terminated, truncated, info = env.step(action)
        steps += 1
        if on_step is not None:
            on_step(obs, info)
        if terminated or truncated:
            break
    progress = info.get("progress")
    return {"steps": steps, "gave_up": gave_up, "success": bool(info.get("success")),
            "progress": None if progress is None else float(progress), "info": info}
