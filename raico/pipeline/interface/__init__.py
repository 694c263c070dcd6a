"""The interfaces: the ``raico`` command line and the Python API."""
