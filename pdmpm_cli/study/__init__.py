"""`pdmpm study`: error against run time over a ladder of resolutions.

`sim` steps a scene built in code (the tests use it too), `problems` holds the verification problems with
analytic references, and `ladder` runs the space and time ladders, fits the orders and writes the CSV and plot.
"""
