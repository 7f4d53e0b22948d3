//! twill-renderer (in progress)
