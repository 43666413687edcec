//! Mesh file I/O: OBJ and PLY (ascii and binary), atomic writes.
