"""``python -m service``: serve on ``MRDEM_HOST``:``MRDEM_PORT`` (see :class:`Settings`)."""

from .cli import serve

if __name__ == "__main__":
    serve()
