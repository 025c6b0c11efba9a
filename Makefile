# The two commands a newcomer needs (see README.md):
#   make demo   set up, then run the demo pipeline on the synthetic actor with the live viewer
#   make test   set up, then run the whole test suite
.PHONY: demo test setup bench

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/mocapgraph launch graph_configs/demo.yaml $(ARGS)

test: setup
	.venv/bin/python -m pytest $(PYTEST_ARGS)

bench: setup
	for b in benchmarks/*.py; do case $$b in *_nodes.py|benchmarks/_*) ;; *) echo "== $$b"; .venv/bin/python $$b;; esac; done
