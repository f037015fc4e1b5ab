"""simeval's own PyBullet task suites: one core (world, arm, end-effectors, objects, cameras, goals, oracle) and
suites written as declarative task specs (YAML), so a new task is a spec, not code."""
