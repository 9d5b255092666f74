"""vibrissa"""
