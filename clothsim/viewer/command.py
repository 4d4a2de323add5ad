"""``clothsim view``: open the viewer on a scene and serve until Ctrl+C or SIGTERM."""

from __future__ import annotations

import math
import signal
import sys
import time

from .. import kernels_cached
from ..config import SceneError, load_scene
from ..material import MaterialError
from ..mold import MoldError
from .guard import is_loopback
from .server import ViewerApp


class _Stop(Exception):
    """Raised in the main thread by the SIGTERM handler: stop like Ctrl+C."""


def _on_sigterm(_signum, _frame) -> None:
    raise _Stop


def main(args) -> int:
    """``clothsim view [scene] [--host H] [--port P] [--upload-limit-mb M] [--no-browser]``.

    Exit status 0 when stopped by Ctrl+C or SIGTERM (the upload folder is removed either way),
    2 for a bad scene or option."""
    if not 0 <= args.port <= 65535:
        print(f"error: --port {args.port}: a port is a whole number from 0 to 65535", file=sys.stderr)
        return 2
    if not (math.isfinite(args.upload_limit_mb) and args.upload_limit_mb >= 0):
        print(f"error: --upload-limit-mb {args.upload_limit_mb}: must be a finite number >= 0", file=sys.stderr)
        return 2
    try:
        scene = load_scene(args.scene)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    host = args.host
    if not is_loopback(host):
        print(f"warning: binding {host}: anyone who can reach this machine on that network and has the "
              f"URL below (its token) can view and drive the simulation, upload files and download results",
              file=sys.stderr)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    app = None
    try:
        # the page is served at once; the model is built and the kernels compiled (a minute and a
        # half on a fresh install, from numba's cache afterwards) in the background, then the run starts
        app = ViewerApp(scene, host=host, port=args.port, upload_limit_mb=args.upload_limit_mb, verbose=True,
                        background=True, autostart=True)
        if app.port != args.port and args.port != 0:
            print(f"note: port {args.port} is busy; using {app.port}", file=sys.stderr)
        print(f"clothsim viewer: {app.url}  (scene {args.scene}; Ctrl+C stops)", flush=True)
        print("loading the compiled kernels from numba's cache..." if kernels_cached() else
              "compiling kernels (first start after an install or update: a minute or two)...",
              file=sys.stderr, flush=True)
        if not args.no_browser:
            try:
                import webbrowser

                webbrowser.open(app.url)
            except Exception:
                pass
        reported = False
        while True:
            time.sleep(0.2)
            if app.ready.is_set() and not reported:
                reported = True
                if app.startup_error is not None:
                    print(f"error: {app.startup_error}", file=sys.stderr)
                    return 2
                print(f"ready in {app.startup_s:.1f} s; relaxing", file=sys.stderr, flush=True)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, _Stop):
        print("\nstopping", file=sys.stderr)
    finally:
        if app is not None:
            app.close()
        signal.signal(signal.SIGTERM, previous)
    return 0
