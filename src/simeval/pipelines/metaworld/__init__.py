"""Meta-World (Yu et al. 2019; `metaworld` 3.1.1 on MuJoCo 3.3) as a simeval pipeline: a human-designed benchmark
with a scripted expert per task, run through the pipeline interface (simeval.pipelines.base) as the reference row
no generative pipeline has."""
