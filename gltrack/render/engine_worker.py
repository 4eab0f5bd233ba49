"""One engine worker process (``python -m gltrack.render.engine_worker``): the other end of
:class:`gltrack.render.workers.EnginePool`.

It makes a GL context, then answers pickled requests on stdin: "score" (build the engine the
request names from its description the first time, apply the observations that changed, score
a share), "drop" (release an engine) and "stop". Replies go to a copy of stdout; stdout itself
is sent to stderr, so stray prints cannot corrupt the replies.
"""
from __future__ import annotations

import os
import pickle
import sys


def _serve(inp, out) -> None:
    """A worker's loop: make a context, then build, score with and drop engines by id."""
    def reply(status, value=None):
        pickle.dump((status, value), out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()

    try:
        from gltrack.gl.context import create_context
        from gltrack.render.engine import ScoringEngine

        ctx = create_context()
    except Exception as e:  # noqa: BLE001 - any failure is the owner's WorkerError
        reply("error", f"could not start: {type(e).__name__}: {e}")
        return
    reply("ok")
    engines = {}
    while True:
        try:
            msg = pickle.load(inp)
        except EOFError:
            break
        if msg[0] == "stop":
            break
        try:
            if msg[0] == "drop":
                eng = engines.pop(msg[1], None)
                if eng is not None:
                    eng.release()
                reply("ok")
                continue
            _, engine_id, spec, state, X, channels, poses = msg
            if engine_id not in engines:
                if spec is None:
                    raise RuntimeError(f"no description of engine {engine_id}")
                engines[engine_id] = ScoringEngine(ctx, spec["mesh"], spec["n_bones"],
                                                   spec["cameras"], workers=0, **spec["options"])
            eng = engines[engine_id]
            for key, value in state:
                eng._apply_mirrored(key, value)
            reply("ok", eng._score_all(X, eng._check_channels(channels), poses))
        except Exception as e:  # noqa: BLE001 - reported to the owner, which falls back
            reply("error", f"{type(e).__name__}: {e}")
    for eng in engines.values():
        eng.release()
    ctx.release()


def main() -> None:
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # prints cannot reach the reply stream
    _serve(sys.stdin.buffer, out)


if __name__ == "__main__":
    main()
