"""``python -m ftcreport.cli``: the command line, as the ``ftcreport`` script runs it."""

from . import app

app()
