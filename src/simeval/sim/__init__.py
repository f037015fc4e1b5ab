"""simeval's own PyBullet task suites: one core (world, arm, end-effectors, objects, cameras, goals, oracle) and
suites written as declarative task specs (YAML), so a new task is a spec, not code.

`make_env` (simeval.sim.env) is the Gymnasium environment; `rollout_policy` (simeval.sim.rollout) rolls a policy
out over seeds. Both are imported lazily, so the rest of the core does not need gymnasium."""

__all__ = ["make_env", "rollout_policy", "OraclePolicy"]


def __getattr__(name: str):
    if name == "make_env":
        from simeval.sim.env import make_env

        return make_env
    if name in ("rollout_policy", "OraclePolicy"):
        from simeval.sim import rollout

        return getattr(rollout, name)
    raise AttributeError(f"module 'simeval.sim' has no attribute {name!r}")
