# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PY      ?= python3.11
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
JOBS    ?= 2

.PHONY: demo test install chromium slurm-packages bench-rasterizer clean-results ablations sweep quality snakemake-report

$(BIN)/python:
	@command -v $(PY) >/dev/null 2>&1 || { echo "Python 3.11 is needed (set PY=/path/to/python3.11)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

# torch first, pinned: its CPU wheel is taken before anything can ask for a CUDA build.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[test]"
	@touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) --configfile config/config.yaml
	@echo "Report: $(CURDIR)/reports/index.html"

# The report's browser test needs Debian's chromium; installed here when missing and possible.
chromium:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing chromium for the report's browser test"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null \
	      || echo "chromium could not be installed: the browser test will skip with the reason"; \
	  else echo "chromium missing and cannot be installed here: the browser test will skip"; fi; }

# The cluster tests (tests/cluster) run a single-node SLURM cluster on this machine
# (workflow/cluster/local-slurm.sh; the tests start and stop it). Its Debian packages are
# installed here when missing and possible; otherwise those tests skip with the reason.
slurm-packages:
	@command -v slurmctld >/dev/null 2>&1 && command -v slurmdbd >/dev/null 2>&1 \
	  && command -v mariadbd >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    echo "installing slurm-wlm, munge, slurmdbd and mariadb-server for the cluster tests"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	      slurm-wlm munge slurmdbd mariadb-server >/dev/null \
	      || echo "SLURM could not be installed: the cluster tests will skip with the reason"; \
	  else echo "SLURM missing and cannot be installed here: the cluster tests will skip"; fi; }

test: $(STAMP) chromium slurm-packages
	$(BIN)/python -m pytest -q

bench-rasterizer: $(STAMP)
	$(BIN)/python benchmarks/bench_rasterizer.py

clean-results:
	rm -rf results .snakemake

# Studies (not part of `make demo`): ablations (paper Table 5) and accuracy versus time; the
# second snakemake call rewrites reports/index.html with their tables.
ablations: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) ablations
	$(BIN)/snakemake --cores $(JOBS)

sweep: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) sweep
	$(BIN)/snakemake --cores $(JOBS)

# The avatar's quality profile (longer than the demo: docs/avatar.md), then the report with it.
quality: $(STAMP)
	$(BIN)/snakemake --cores $(JOBS) quality
	$(BIN)/snakemake --cores $(JOBS)

# Snakemake's own report (captions in workflow/report/) over the finished outputs.
snakemake-report: $(STAMP)
	$(BIN)/snakemake --report reports/snakemake.html
