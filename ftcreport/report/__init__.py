"""Reports at the edge: figures (SVG), HTML pages (Jinja2), JUnit XML."""
