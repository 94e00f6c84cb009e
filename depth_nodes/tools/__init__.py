"""The `depth-nodes` command (cli/, one module per command) and its parts: bags/, live/,
evaluation/, bench/."""
