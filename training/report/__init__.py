"""Reports: figures, the HTML report and the demo that writes one."""
