"""One thin module per node: subscribe, convert, call core, publish."""
