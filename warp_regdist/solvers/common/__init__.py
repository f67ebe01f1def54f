"""What both solvers share: the ADMM loop and penalty schedule (``admm``), the stopping rule (``stopping``),
progress reports (``progress``), Ctrl-C and SIGTERM (``interrupt``), worker processes (``processes``), the
operators on the device (``device_mesh``), the constraint of every element and column
(``source_triangles``) and the results (``results``)."""
