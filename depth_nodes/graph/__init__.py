"""Graphs of nodes: a YAML graph description (schema.py; description.py gathers the public
names), a graph moved to a camera driver's names (cameras.py), parameter files matched to
its nodes (parameter_files.py), the nodes created (factory.py), and the launch files' side
(launching.py, launch_file.py). The composed pipeline, the offline harness and the launch
files all read graphs through here."""
