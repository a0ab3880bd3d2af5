"""One function per DVC stage: compose the packages, write the outputs, log the run.

`stages/*.py` are thin Hydra shells around these, so tests call the same code with a
composed config and a temporary project root.
"""

from uqdrive.resolvers import register_resolvers

register_resolvers()
