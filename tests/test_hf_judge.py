"""The local `transformers` judge, run for real on a tiny randomly initialised LLaVA built here (a tiny config
stands in for a big model; nothing is downloaded). Its replies are noise, which also exercises the path where
a judge never gives a parseable score."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simeval.judges.providers import HFVisionProvider, Image

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_llava(tmp_path_factory) -> Path:
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers
    from transformers import (CLIPImageProcessor, CLIPVisionConfig, LlamaConfig, LlavaConfig,
                              LlavaForConditionalGeneration, LlavaProcessor, PreTrainedTokenizerFast)

    words = "score : 0 1 2 3 4 5 6 7 8 9 10 task description frames views scene system user assistant".split()
    vocab = {t: i for i, t in enumerate(["<unk>", "<s>", "</s>", "<image>", "<pad>", *words])}
    tok = Tokenizer(models.WordLevel(vocab, unk_token="<unk>"))
    tok.pre_tokenizer = pre_tokenizers.WhitespaceSplit()
    tokenizer = PreTrainedTokenizerFast(tokenizer_object=tok, unk_token="<unk>", bos_token="<s>", eos_token="</s>",
                                        pad_token="<pad>", additional_special_tokens=["<image>"])
    template = ("{% for m in messages %}{{ m['role'] }}: {% for c in m['content'] %}{% if c['type'] == 'image' %}"
                "<image> {% else %}{{ c['text'] }} {% endif %}{% endfor %}{% endfor %}"
                "{% if add_generation_prompt %}assistant: {% endif %}")
    vision = CLIPVisionConfig(hidden_size=16, intermediate_size=32, num_hidden_layers=1, num_attention_heads=2,
                              image_size=32, patch_size=16, projection_dim=16)
    text = LlamaConfig(vocab_size=len(tokenizer), hidden_size=16, intermediate_size=32, num_hidden_layers=1,
                       num_attention_heads=2, num_key_value_heads=2, max_position_embeddings=512, pad_token_id=4)
    torch.manual_seed(0)
    model = LlavaForConditionalGeneration(LlavaConfig(vision_config=vision, text_config=text, vision_feature_layer=-1,
                                                      image_token_index=vocab["<image>"]))
    processor = LlavaProcessor(image_processor=CLIPImageProcessor(size={"shortest_edge": 32},
                                                                  crop_size={"height": 32, "width": 32}),
                               tokenizer=tokenizer, patch_size=16, vision_feature_select_strategy="full",
                               chat_template=template)
    path = tmp_path_factory.mktemp("tiny_llava")
    model.save_pretrained(path)
    processor.save_pretrained(path)
    return path


def test_local_vlm_answers_with_images(tiny_llava):
    provider = HFVisionProvider(str(tiny_llava), max_new_tokens=4, temperature=0.0)
    frames = [Image.from_array(np.full((40, 40, 3), i * 30)) for i in range(3)]
    first = provider.complete("You grade.", "task description", frames)
    again = provider.complete("You grade.", "task description", frames)
    assert first.text and first.text == again.text  # greedy decoding: deterministic
    assert first.completion_tokens > 0 and first.latency_s > 0
    assert provider.decoding == {"temperature": 0.0, "max_new_tokens": 4}


def test_quality_with_the_local_judge_records_unparseable_replies(tiny_llava, tmp_path):
    from helpers import make_bundles

    root = make_bundles(tmp_path / "b", n=1)
    res = subprocess.run([sys.executable, str(ROOT / "src" / "quality.py"), f"bundles_dir={root}", "judge=hf",
                          f"judge.provider.model_path={tiny_llava}", "judge.provider.max_new_tokens=4",
                          "judge.provider.temperature=0.0", "repeats=2", "max_reasks=1", "metric=task_completion",
                          f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={tmp_path / 'run'}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ})
    rec = json.loads((tmp_path / "run" / "result.json").read_text())
    entry = rec["values"]["task_completion"]["task0"]
    # the tiny model is seeded and decodes greedily: its replies are the same noise every run, never a score, so
    # the one task fails and with it the run (exit 1, the reason on one line), and every call is paid for nothing
    assert entry["n_valid"] == 0 and entry["n_invalid"] == 2 and entry["mean"] is None
    assert res.returncode == 1 and rec["status"] == "failed", res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1].startswith("error: every task failed (1 of 1; task0: ")
    assert rec["cost"]["invalid_calls"] == rec["cost"]["new_calls"] >= 2
    lines = [json.loads(x) for x in (tmp_path / "run" / "scores.jsonl").read_text().splitlines()]
    assert len(lines) == 2 and all(x["provider"] == "hf" and x["asks"][0]["reply"] for x in lines)
    assert entry["n_valid"] + entry["n_invalid"] == 2
    for x in lines:  # whatever the noise said, it was parsed honestly: a number only if it was a valid score
        assert (x["score"] is None) == all(not a["valid"] for a in x["asks"])


def test_concurrent_requests_are_batched(tiny_llava):
    from concurrent.futures import ThreadPoolExecutor

    provider = HFVisionProvider(str(tiny_llava), max_new_tokens=3, temperature=0.0, batch_size=4, batch_wait_s=0.5)
    sizes = []
    run_batch = provider._run_batch
    provider._run_batch = lambda convs: sizes.append(len(convs)) or run_batch(convs)
    frames = [Image.from_array(np.full((40, 40, 3), 50))]
    with ThreadPoolExecutor(8) as pool:
        replies = list(pool.map(lambda i: provider.complete("You grade.", f"task {i}", frames), range(8)))
    assert sum(sizes) == 8 and max(sizes) > 1 and len(sizes) < 8  # 8 requests in fewer, larger forward passes
    assert all(r.text for r in replies)
