# uwb-rig: `make demo` sets everything up and runs the main job; `make test` runs the tests.
VENV := .venv
RIG := $(VENV)/bin/rig
PYTEST := $(VENV)/bin/pytest

.PHONY: setup demo test default-recording clean

setup:
	./scripts/setup.sh

demo: setup
	$(RIG) demo --out out/demo

test: setup
	$(PYTEST) -q

# Regenerates recordings/default.mcap byte for byte from its config.
default-recording: setup
	$(RIG) simulate --config recordings/default.sim.json -o recordings/default.mcap

clean:
	rm -rf out build estimator_c/build
