"""The live panel: a browser page that controls and watches a 1 kHz session (issue 15).

`server.py` (Starlette on uvicorn, the optional extra `carfeel[panel]`) serves the page and its
JSON + WebSocket API; `worker.py` runs the loop in its own process; `ring.py` is the shared
memory between them; `tuning.py` validates and sizes live parameter changes.
"""
