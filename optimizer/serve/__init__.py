"""``shoha serve``: live checks of a trainee's layout over HTTP and WebSocket (docs/serve.md).

* :mod:`.live`: a layout whose checks (porosity, tolerance, collisions,
  crest) follow each block, exactly as ``shoha check`` finds them;
* :mod:`.bodies`: request bodies, parsed strictly and checked whole;
* :mod:`.session`: sessions, their state and their watchers;
* :mod:`.hint`: the next block to lay, from the reference or a re-plan;
* :mod:`.workers`: references, scores and re-plans in other processes;
* :mod:`.service`: every endpoint, apart from HTTP;
* :mod:`.app`: the web layer (Starlette on uvicorn); :mod:`.openapi`, :mod:`.view`.
"""
