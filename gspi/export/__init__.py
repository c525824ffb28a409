"""glTF 2.0 export of a PBR-GS asset (gspi-export asset=...): mesh, UV atlas, baked textures."""
