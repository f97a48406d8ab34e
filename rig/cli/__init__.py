"""The ``rig`` command line: thin typer commands over library functions."""
