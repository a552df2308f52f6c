"""Shape geometry: readers (OBJ/MTL, glTF/GLB, Sweet Home 3D catalogs, ShapeNet layout), safe archive
access, preprocessing into the mesh contract (`mesh.ShapeMesh`), crease-aware normals, UVs, and an
isolated worker for untrusted input. Pure functions on files and arrays: no database, no Prefect."""
