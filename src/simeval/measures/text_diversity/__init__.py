"""Text diversity of task descriptions (paper Eq. 1, Table 3): `metric` (the formula), `run` (a pipeline's task
groups through an encoder), `table3` (records to Table 3's cells), `report` (every artefact of a report spec)."""
