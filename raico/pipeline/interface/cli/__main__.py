"""``python -m raico.pipeline.interface.cli``: the ``raico`` command."""

from raico.pipeline.interface.cli import main

if __name__ == "__main__":
    main()
