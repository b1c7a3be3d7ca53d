"""The web service and viewer behind `sinrun serve` (needs the serve extra).

    from sinshape.serve import app
    application = app.create_app(app.load_models(["terrain"]))   # an ASGI app

The routes only parse, call the runtime (sample, extract, dense, write) and
answer; the runtime knows nothing about HTTP. The page at / and its
three.js files are static files in serve/static.

It imports FastAPI, pydantic and the runtime (and the shipped models),
never torch, the trainer or the CLI.
"""
