"""``svbrdf-models serve``: a model behind a guarded HTTP server (:mod:`svbrdf_models.modelfile.serve`)."""

from __future__ import annotations

import argparse

from svbrdf_render.plumbing import MAX_THREADS, THREADS_HELP, float_range, int_range

from .._registry import Registry
from ..modelfile.serve_limits import ServeLimits

__all__ = ["add_parser", "run"]

EPILOG_SERVE = """\
examples:
  svbrdf-models serve                                   # the shipped model on 127.0.0.1:5001
  svbrdf-models serve models:/svbrdf-ours/1 --port 8080 # a registered model (needs mlflow)
  curl 127.0.0.1:5001/invocations -H 'Content-Type: application/json' \\
       -d '{"inputs": [[[[0.5, 0.4, 0.3], ...]]], "params": {"refine": 0}}'

The protocol is MLflow's (what `mlflow models serve` answers): "inputs" holds linear RGB
photos in [0, 1], channels last, (N, H, W, 3); the answer is {"predictions": {"normal": ...,
"diffuse": ..., "roughness": ..., "specular": ...}}: at refine 0 maps of the model's size
(128 px), refined maps at the photo's shorter side. Every limit is checked before any work,
the answer's size, memory and time estimated from the photos' shape, and a refusal is one
line of text (413 body too large, 400 bad photo or parameter or a request over a limit, 408
upload stalled or too slow, 415 not JSON, 503 busy or too many connections, 504 late). The
timeout covers the whole request; a refinement gets what the other stages leave and stops with
the maps it reached; the Server-Timing header says each stage's seconds. GET /ping answers 503 while a request holds the worker past its timeout. The log has
one line per kind of failure every 10 s. SIGTERM or Ctrl-C ends the server and its work.
Needs svbrdf-models[mlflow] (starlette and uvicorn).
"""


def add_parser(sub) -> None:
    """The ``serve`` sub-command and its options."""
    d = ServeLimits  # the defaults, read off the class
    p = sub.add_parser(
        "serve",
        help="serve a model over HTTP (MLflow's protocol), with limits a client cannot break",
        description="Serve a model file or registered model: POST /invocations, GET /ping.",
        epilog=EPILOG_SERVE,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("source", nargs="?", default="pretrained",
                   help="a model file, models:/NAME/VERSION, runs:/ID/PATH or pretrained[:NAME] (default: "
                   "the model shipped with this package)")  # fmt: skip
    p.add_argument("--host", default="127.0.0.1", help="address to listen on [127.0.0.1: this machine]")
    p.add_argument("--port", type=int_range(1, 65535), default=5001, help="port [5001]")
    p.add_argument("--max-body-mb", type=float_range(0, above=True), default=d.body_mb, metavar="MB",
                   help=f"largest request body [{d.body_mb:g}]; a 2048 px photo is 60-120 MB of JSON")  # fmt: skip
    p.add_argument("--max-photos", type=int_range(1), default=d.photos, metavar="N",
                   help=f"photos in one request [{d.photos}]; each is its own network pass and maps, so send "
                   "more in several requests")  # fmt: skip
    p.add_argument("--max-pixels", type=int_range(1), default=d.pixels, metavar="N",
                   help=f"pixels of all the photos of one request [{d.pixels:,}]")  # fmt: skip
    p.add_argument("--max-refine", type=int_range(0), default=d.refine, metavar="STEPS",
                   help=f"refinement steps one request may ask [{d.refine}]")  # fmt: skip
    p.add_argument("--max-answer-mb", type=float_range(0, above=True), default=d.answer_mb, metavar="MB",
                   help=f"largest answer, estimated before any work [{d.answer_mb:g}]; 10 values a "
                   "pixel, about 11 bytes each: a 128 px material is 1.7 MB, a 1024 px refined one "
                   "110 MB")  # fmt: skip
    p.add_argument("--timeout", type=float_range(1), default=d.timeout, metavar="S",
                   help=f"seconds a request may take, upload, queue and answer included [{d.timeout:g}]; "
                   "one that cannot end in time is refused before any work, a refinement stops in "
                   "time")  # fmt: skip
    p.add_argument("--read-timeout", type=float_range(0, above=True), default=d.read_timeout, metavar="S",
                   help=f"seconds an upload may go without a byte (then 408), and a connection may take "
                   f"to send its request's headers (then it is closed) [{d.read_timeout:g}]")  # fmt: skip
    p.add_argument("--max-connections", type=int_range(1), default=d.connections, metavar="N",
                   help=f"connections at once [{d.connections}]; beyond, a request is answered 503; at "
                   "most the open-file limit (ulimit -n) less 64")  # fmt: skip
    p.add_argument("--threads", type=int_range(1, MAX_THREADS), metavar="N", help=THREADS_HELP)


def run(args, registry: Registry, out) -> None:
    from svbrdf_render.plumbing import choose_threads

    from ..modelfile.files import load_model
    from ..modelfile.serve import check_open_files, serve

    limits = ServeLimits(body_mb=args.max_body_mb, pixels=args.max_pixels, refine=args.max_refine,
                         timeout=args.timeout, photos=args.max_photos, answer_mb=args.max_answer_mb,
                         read_timeout=args.read_timeout, connections=args.max_connections)  # fmt: skip
    check_open_files(limits)  # before the model loads: a bad value is one line at once
    choice = choose_threads(args.threads)
    model = load_model(args.source)

    def say(line: str) -> None:
        print(f"{line}; {choice.describe()}", file=out, flush=True)

    serve(model, args.host, args.port, limits, say=say)
