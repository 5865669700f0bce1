"""manipulation"""
