# The two commands a newcomer needs (see README.md):
#   make demo   set up, then run the demo pipeline on the synthetic actor with the live viewer
#   make test   set up, then run the whole test suite
#   (make test-fast: the fast subset for the edit-test loop, pytest -m "not slow")
#   (make bench: every benchmark, rewriting benchmarks/RESULTS.md; BENCH_ARGS="bus solver" refreshes just those)
.PHONY: demo test test-fast setup bench

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/mocapgraph launch graph_configs/demo.yaml $(ARGS)

test: setup
	.venv/bin/python -m pytest $(PYTEST_ARGS)

test-fast: setup
	.venv/bin/python -m pytest -m "not slow" $(PYTEST_ARGS)

bench: setup
	.venv/bin/python benchmarks/_run_all.py $(BENCH_ARGS)
