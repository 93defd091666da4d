# uwb-rig: `make demo` sets everything up and runs the main job; `make test` runs the tests.
VENV := .venv
RIG := $(VENV)/bin/rig
PYTEST := $(VENV)/bin/pytest

.PHONY: setup demo test test-fast default-recording room-bias-net link-bias clean

setup:
	./scripts/setup.sh

demo: setup
	$(RIG) demo --out out/demo

# The whole suite: two workers (a test file stays on one; BLAS single-threaded in each,
# or four spinning threads fight over two cores), then the tests that measure time as it
# passes, alone, so that the other worker's load does not make them late.
test: setup
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PYTEST) -q -n 2 --dist loadfile -m "not serial" --durations=15
	$(PYTEST) -q -m serial

# What to run while working (under 3 minutes): the C unit tests, then every test not
# marked slow (unit tests and one short native replay).
test-fast: setup
	$(MAKE) -s -C estimator_c check
	$(PYTEST) -q -m "not slow"

# Regenerates recordings/default.mcap byte for byte from its config.
default-recording: setup
	$(RIG) simulate --config recordings/default.sim.json -o recordings/default.mcap

# The pose-dependent bias the default recording carries beside its calibrated `link_bias`
# (its `learned_bias`): a pairwise network of what the link bias leaves of the error,
# trained only on flights the pairwise network shipped before the link form
# (recordings/pair_bias_net.json, `rig train --form pair`) did not train on
# (docs/notebook/diagnosis.md).
room-bias-net: setup
	$(RIG) train --form pair --apart-from recordings/pair_bias_net.json --minus-link-bias \
		--out recordings/room_bias_net.json

# The link bias every tag-anchor link shares, fitted to the 35 shared flights: the shape
# the diagnosis names as `link_bias` (docs/reference/diagnosis.md).
link-bias: setup
	$(RIG) calibrate --out rig/sim/effects/link_bias.json

clean:
	rm -rf out build estimator_c/build
