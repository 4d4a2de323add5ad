"""``clothsim view``: open the viewer on a scene and serve until Ctrl+C."""

from __future__ import annotations

import sys
import time

from ..config import SceneError, load_scene
from ..material import MaterialError
from ..mold import MoldError
from .server import ViewerApp


def is_loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


def main(args) -> int:
    """``clothsim view [scene] [--host H] [--port P] [--upload-limit-mb M] [--no-browser]``."""
    try:
        scene = load_scene(args.scene)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    host = args.host
    if not is_loopback(host):
        print(f"warning: binding {host}: anyone who can reach this machine on that network can view and "
              f"drive the simulation, upload files and download results", file=sys.stderr)
    try:
        app = ViewerApp(scene, host=host, port=args.port, upload_limit_mb=args.upload_limit_mb, verbose=True)
    except (SceneError, MoldError, MaterialError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if app.port != args.port:
        print(f"note: port {args.port} is busy; using {app.port}", file=sys.stderr)
    print(f"clothsim viewer: {app.url}  (scene {args.scene}; Ctrl+C stops)", flush=True)
    if not args.no_browser:
        try:
            import webbrowser

            webbrowser.open(app.url)
        except Exception:
            pass
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("\nstopping", file=sys.stderr)
    finally:
        app.close()
    return 0
