"""Test and demo helpers: simulated devices, test-pattern and stage nodes, the arm jig.

Nothing in the pipeline imports this package; tests, benchmarks, example graphs and
`mocapgraph device simulate` do.
"""
