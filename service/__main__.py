"""``python -m service``: serve on ``MRDEM_HOST``:``MRDEM_PORT`` (see :class:`Settings`);
``mrdem serve`` without its flags."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main(["serve"]))
