"""What reads every measurement at once, above them: `rebuild` (every table and figure from result.json files, the
report door's functions), `html` (one static page of a run or sweep folder), `scorecard` (one pipeline's readings
beside the committed reference rows). Generic table and figure writing stays in simeval.report, below the
measurements."""
