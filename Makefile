# Two-command set-up: `make race` and `make test` each bootstrap .venv on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: race test lint format bench docs docs-media train-generalist train-specialists build-detector clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first, exactly pinned, so the local CPU build is taken before anything asks for torch.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	# Compile the detector's numba code once here, so that no race or test pays for it.
	$(BIN)/python -m icarus_vision.racing.warmup
	touch $(STAMP)

# `make race` flies the default race with the shipped CNN detector and policy; pass options with
# e.g. `make race ARGS="--track ten-gates --randomize"`.
ARGS ?=

race: $(STAMP)
	$(BIN)/icarus-vision race $(ARGS)

test: $(STAMP)
	$(BIN)/python -m pytest

lint: $(STAMP)
	$(BIN)/ruff check icarus_vision tests benchmarks tools
	$(BIN)/ruff format --check icarus_vision tests benchmarks tools

format: $(STAMP)
	$(BIN)/ruff format icarus_vision tests benchmarks tools
	$(BIN)/ruff check --fix icarus_vision tests benchmarks tools

# The documentation site (mkdocs-material) into site/; the test suite builds it with --strict.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# The README's animation (docs/race.gif): plans grand-prix, flies it with the shipped models.
docs-media: $(STAMP)
	$(BIN)/python tools/race_gif.py --out docs/race.gif

# The shipped racing generalist (icarus_vision/models/policy/default.*: the twelfth part's average,
# the mean of the weights of its last five evaluated policies). Twelve runs, each from the one
# before (the second run's best.* is shipped as racing.*, which the specialists start from): about
# 180 minutes on 2 cores. See docs/policy.md.
train-generalist: $(STAMP)
	$(BIN)/icarus-vision train-policy --config configs/policy-racing.toml --seed 0 --out runs/policy-racing --timesteps 34013184
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-speed.toml --seed 0 --out runs/policy-racing-speed --timesteps 29008384
	cp runs/policy-racing-speed/best.json icarus_vision/models/policy/racing.json
	cp runs/policy-racing-speed/best.safetensors icarus_vision/models/policy/racing.safetensors
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-vision.toml --seed 0 --out runs/policy-racing-vision --timesteps 33411328
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-vision-more.toml --seed 0 --out runs/policy-racing-vision-more --timesteps 20000000
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-gateframe.toml --seed 0 --out runs/policy-racing-gateframe --timesteps 20000000
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-gateframe-more.toml --seed 0 --out runs/policy-racing-gateframe-more --timesteps 20000000
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-replay.toml --seed 0 --out runs/policy-racing-replay --timesteps 20000000
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-replay-more.toml --seed 0 --out runs/policy-racing-replay-more --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-replay-more --last 5
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-replay-mapshare.toml --seed 0 --out runs/policy-racing-replay-mapshare --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-replay-mapshare --last 5
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-critic.toml --seed 0 --out runs/policy-racing-critic --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-critic --last 5
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-critic-tc4.toml --seed 0 --out runs/policy-racing-critic-tc4 --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-critic-tc4 --last 5
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-critic-view.toml --seed 0 --out runs/policy-racing-critic-view --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-critic-view --last 5
	$(BIN)/icarus-vision train-policy --config configs/policy-racing-bias.toml --seed 0 --out runs/policy-racing-bias --timesteps 20000000
	$(BIN)/icarus-vision average-policy runs/policy-racing-bias --last 5
	cp runs/policy-racing-bias/average.json icarus_vision/models/policy/default.json
	cp runs/policy-racing-bias/average.safetensors icarus_vision/models/policy/default.safetensors

# The shipped detector (models/detector/) from nothing, in its two parts (docs/detection.md).
build-detector: $(STAMP)
	$(BIN)/icarus-vision build-detector --config configs/detector-build.toml --out runs/detector-build
	$(BIN)/icarus-vision build-detector --config configs/detector-v5-build.toml --out runs/detector-v5
	cp runs/detector-v5/detector/* icarus_vision/models/detector/

# The shipped specialists (models/policy/<track>-specialist.*), side by side: grand-prix from the
# generalist's twelfth part (runs/policy-racing-critic-view/average: run train-generalist first),
# split-s from `racing` (its run's final policy.*). About 15 minutes on 2 cores.
train-specialists: $(STAMP)
	$(BIN)/icarus-vision train-policy --config configs/policy-specialist-grand-prix-v2.toml --seed 0 --out runs/specialist-grand-prix-v2 --timesteps 23511296 & \
	$(BIN)/icarus-vision train-policy --config configs/policy-specialist-split-s.toml --seed 0 --out runs/specialist-split-s --max-minutes 15; wait
	$(BIN)/icarus-vision average-policy runs/specialist-grand-prix-v2 --last 5
	cp runs/specialist-grand-prix-v2/average.json icarus_vision/models/policy/grand-prix-specialist.json
	cp runs/specialist-grand-prix-v2/average.safetensors icarus_vision/models/policy/grand-prix-specialist.safetensors
	cp runs/specialist-split-s/policy.json icarus_vision/models/policy/split-s-specialist.json
	cp runs/specialist-split-s/policy.safetensors icarus_vision/models/policy/split-s-specialist.safetensors

bench: $(STAMP)
	$(BIN)/python benchmarks/sim_throughput.py

clean:
	rm -rf $(VENV) build site *.egg-info
