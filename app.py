"""clothsim entry point: ``python app.py`` opens the viewer on the default scene and
``python app.py SCENE.yaml`` on that scene; ``python app.py run|sweep|bench|view ...`` for headless
work (see ``python app.py --help`` and ``python app.py CMD --help``)."""

import sys

from clothsim.cli import main

if __name__ == "__main__":
    sys.exit(main())
