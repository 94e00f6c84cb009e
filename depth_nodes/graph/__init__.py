"""Graphs of nodes: a YAML graph description (description.py: the nodes, their remappings
and parameters) and the launch-file arguments built on it (launching.py); the pipeline,
the offline harness and the launch files all read graphs through here."""
