//! Model diagnostics: compare model and measurement, rank candidate effects, model ladder, SVG plots. Pure.
