"""Small shared geometry: similarity alignment and rotation distances (numpy), mesh normals
(torch)."""
