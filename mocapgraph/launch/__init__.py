"""Launch graphs: YAML loading (args, includes, remaps, expects), checks, the wiring plan, supervision, serving the manifest."""
