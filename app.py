"""clothsim entry point: ``python app.py`` opens the viewer on the default scene;
``python app.py run|sweep|bench|view ...`` for headless work (see ``python app.py --help``)."""

import sys

from clothsim.cli import main

if __name__ == "__main__":
    sys.exit(main())
