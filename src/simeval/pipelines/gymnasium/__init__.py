"""Any Gymnasium environment as a pipeline, by its config alone (simeval.pipelines.gymnasium.pipeline)."""
