"""``python -m ftcreport``: the command line, as the ``ftcreport`` script runs it."""

from .cli import app

app(prog_name="ftcreport")
