"""A live graph: composed into one process (pipeline) or run as node processes
(processes), and looked at: nodes, topics, parameters, diagnostics."""
