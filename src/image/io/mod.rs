//! HDR and 8-bit file formats.
