"""Files in and out: safe reading, atomic writing, messages for bad input, the measurements table
and its CSV, foreign logs.
"""
