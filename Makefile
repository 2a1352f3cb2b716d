# airpuff: `make demo` sets up .venv if missing and runs the main job; `make test` runs the suite.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
OUT    ?= demo_out
export NUMBA_CACHE_DIR ?= $(CURDIR)/.numba_cache

.PHONY: venv demo test bench image clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[all,test]'
	@touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(PY) -m sweep.demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q tests

# The Docker image airpuff:local (docker/build.sh, README.md "Running on a cluster").  Where the
# package index is reached only through the host's network and a TLS proxy:
#   make image IMAGE_BUILD_ARGS="--network host --ca-bundle /path/to/ca-bundle.crt"
image:
	docker/build.sh $(IMAGE_BUILD_ARGS)

bench: $(STAMP)
	$(PY) -m benchmarks.run_all

clean:
	rm -rf $(OUT) .numba_cache .pytest_cache
