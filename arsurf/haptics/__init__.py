"""haptics"""
