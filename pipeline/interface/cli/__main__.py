"""``python -m pipeline.interface.cli``: the ``raico`` command."""

from pipeline.interface.cli import main

if __name__ == "__main__":
    main()
