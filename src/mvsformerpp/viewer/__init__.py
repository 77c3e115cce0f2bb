"""What a user looks at: the HTML report of an output folder and the browser viewer (presentation only).

Both read a ``reconstruct`` output folder and never change it (the report is written beside it).
"""
