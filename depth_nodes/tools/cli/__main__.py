"""``python -m depth_nodes.tools.cli``: the `depth-nodes` command."""

import sys

from depth_nodes.tools.cli import main

sys.exit(main())
