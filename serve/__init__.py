"""The web service and viewer behind `sinrun serve` (needs the serve extra).

    from sinshape.serve import app
    application = app.create_app(app.load_models(["terrain"]))   # an ASGI app

The routes (app.py) only parse, build the runtime's request, call one
function and answer; the sampler (sampler.py) schedules, shares and caches
what jobs make (jobs.py); http.py holds what every answer gets. The runtime
knows nothing about HTTP. The page at / and its three.js files are static
files in serve/static; `sinrun export-web` writes them as a site (site.py)
with its own standalone server (site_server.py).

It imports FastAPI, pydantic and the runtime (and the shipped models),
never torch, the trainer or the CLI.
"""
