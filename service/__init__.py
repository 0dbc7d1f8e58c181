"""Service: wire messages, zenoh wiring, workers, CLI, rerun bridge, config.

Modules (imported on demand so that the CLI starts fast):

- ``messages``: binary wire records (``FrameMessage``, ``ChamferMessage``) and ``MessageError``
- ``records``: JSON wire records (``PoseRecord``, ``StatusMessage``, ``CreditMessage``)
- ``bus``: key names, zenoh settings/sessions, bounded inboxes, credits, liveliness and status
- ``config``: the studio TOML (``load_config``)
- ``assembler``: frame sets by frame id (live newest-wins, lossless in order)
- ``workers``: the camera, segment and track loops; ``components``: adapters to segmentation/tracker
- ``runtime``: building a worker's parts from the config; ``supervisor``: ``contourcap run``
- ``viewer``: rerun bridge; ``export``: JSONL/BVH; ``demo``: the synthetic end-to-end demo
"""
