"""The `depth-nodes` command: generate, process, play, record, eval."""
