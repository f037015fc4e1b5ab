"""Per-pipeline code that runs a pipeline's own software (simeval.pipelines.<name>): GenSim's own tasks so far."""
