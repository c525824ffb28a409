"""`gspi-report`: a static HTML site (and the paper's figures) from run and sweep folders."""
