# coopsumo: every target creates .venv and installs what it needs on first use.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
DEMO_OUT ?= results/demo
QUICK   ?=
SEEDS   ?=
TRAIN_SEEDS ?=
PRESET  ?=
ALPHAS  ?=
FULL    ?=
T_UP    ?=
MOBIL_P ?=
PROFILE ?=
# torch from PyPI by default (on Linux x86-64 its CUDA build); TORCH_INDEX=https://download.pytorch.org/whl/cpu takes the
# CPU build from PyTorch's index (pip --index-url, as PyTorch's instructions for CPU-only machines). It acts when the
# .venv is installed: in a new checkout, or after make clean
TORCH_INDEX ?=

.PHONY: install test lint bench demo nets scenario1 scenario2 learning protocol regime-map clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip "setuptools>=74.1"  # setuptools: the wheel test builds without isolation
	$(BIN)/pip install --quiet torch==2.13.0$(if $(TORCH_INDEX), --index-url $(TORCH_INDEX))
	$(BIN)/pip install --quiet -e ".[dev,sb3,ray,tensorboard]"
	touch $(STAMP)

install: $(STAMP)

# one line per test file as it ends ([ 37%] tests/test_x.py: 42 passed in 95.2 s; tests/file_progress.py) instead
# of dots: with -n 2 pytest names no file, and -v would print a line per test. --no-loadscope-reorder: the files
# are handed out in collection order, the slowest first (tests/conftest.py, SLOWEST_FIRST); xdist's default order,
# the most tests first, had the slowest files end last, one process busy alone
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile --no-loadscope-reorder --file-progress -o console_output_style=classic --durations=25

lint: $(STAMP)
	$(BIN)/ruff check coopsumo tests experiments
	$(BIN)/mypy coopsumo

bench: $(STAMP)
	$(BIN)/coopsumo bench $(BENCH_ARGS)

demo: $(STAMP)
	$(BIN)/coopsumo simulate --scenario free --lanes 3 --policy greedy --steps 3000 --seed 1 --out $(DEMO_OUT)
	@echo "demo: wrote the run folder $(DEMO_OUT)/ (what it holds: docs/run-folders.md)"

nets: $(STAMP)
	$(BIN)/python -c "from coopsumo.config import RoadConfig; from coopsumo.sim.network import build_net; [print(build_net(RoadConfig(lanes=n))) for n in range(2, 7)]"

scenario1: $(STAMP)
	$(BIN)/coopsumo scenario1 $(if $(PROFILE),--profile $(PROFILE)) $(if $(QUICK),--quick) $(if $(FULL),--full) $(if $(SEEDS),--seeds $(SEEDS)) $(if $(TRAIN_SEEDS),--train-seeds $(TRAIN_SEEDS)) $(if $(T_UP),--t-up $(T_UP)) $(if $(MOBIL_P),--mobil-p $(MOBIL_P)) $(if $(PRESET),--preset $(PRESET)) $(if $(ALPHAS),--alphas $(ALPHAS))

# the full profile (issue 65: a model per alpha and lane count, baselines, the gate); PROFILE=check its check
scenario2: $(STAMP)
	$(BIN)/coopsumo scenario2 $(if $(PROFILE),--profile $(PROFILE))

# the learner ablation (the chain from the paper's learner to the default) as the protocol's learning profile
learning: $(STAMP)
	$(if $(QUICK)$(PROFILE),$(error make learning takes no QUICK or PROFILE since the learning study became the protocol's learning profile (issue 80): try make protocol PROFILE=tiny))
	$(BIN)/coopsumo protocol --profile learning

# without PROFILE the profile judging today's default learner (protocol_plan.CURRENT); each writes its own folder
protocol: $(STAMP)
	$(BIN)/coopsumo protocol $(if $(PROFILE),--profile $(PROFILE))

regime-map: $(STAMP)
	$(BIN)/coopsumo scenario1 --regime-map $(if $(SEEDS),--seeds $(SEEDS))

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
