"""What reads every measurement at once, above them (what src/report.py runs): `rebuild` (every table and figure
from result.json files, the report door's functions), `html` (one static page of a run or sweep folder),
`scorecard` (one pipeline's readings beside the committed reference rows). Generic table and figure writing is in
simeval.writing, below the measurements."""
