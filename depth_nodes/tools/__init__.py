"""The `depth-nodes` command (cli.py) and its parts: bags/, live/, evaluation/, bench/."""
