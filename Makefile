# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PY      ?= python3.11
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
JOBS    ?= 2

.PHONY: demo test install chromium bench-rasterizer clean-results ablations sweep quality snakemake-report

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

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q $(if $(TORCH_INDEX),--extra-index-url $(TORCH_INDEX)) "$(TORCH)"
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

# The suite on $(JOBS) workers (pytest-xdist; work stealing, as a few end-to-end runs are long);
# pytest prints its time and the slowest tests at the end.
test: $(STAMP) chromium
	$(BIN)/python -m pytest -q -n $(JOBS) --dist worksteal --durations=15

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
