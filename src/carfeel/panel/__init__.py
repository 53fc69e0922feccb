"""The live panel: a browser page that controls and watches a 1 kHz session (issue 15).

`server.py` (Starlette on uvicorn, the optional extra `carfeel[panel]`) serves the page and its
JSON + WebSocket API over `state.py` (the panel's folder and its one session), `auth.py` (the
guard), `stream.py` (the WebSocket frames), `session.py` (the loop's process as the panel sees
it), `choices.py` (what a session may be), `recordings.py` and `saving.py` (the folder's files),
`values.py` and `config.py`; `worker.py` runs the loop in its own process; `ring.py` is the shared
memory between them; `tuning.py` validates and sizes live parameter changes; `plotting.py` draws
the recordings' plots in a worker process.
"""
