"""Sub-commands of the ``contourcap`` CLI (see ``service/cli.py``)."""
