"""Small shared geometry (numpy): similarity alignment and rotation distances."""
