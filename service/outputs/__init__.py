"""Outputs people plug into: TRC, C3D and CSV marker files, the VMC (OSC) and WebSocket streams.

``timeline``: the pose records on the session's frame grid; ``trc``/``c3d``/``csv``: marker files;
``smoothing``: the 1€ filter over pose records; ``vmc``/``ws``: live bridges (``contourcap stream``).
"""
