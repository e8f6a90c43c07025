"""Beside the flow: the simulator, simulated sessions and robots, the paper's study (production
code never imports it; the application uses it for ``simulate``, ``demo``, ``study`` and
``--mock``).
"""
