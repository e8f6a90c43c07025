"""The application on top: the workflow every front end calls, the CLI with one module per command,
the demo and the text report.
"""
