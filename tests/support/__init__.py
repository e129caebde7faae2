"""What the tests share, one module per job: toy sites, plans and phones, made-up lab data,
the recorded datasets' folders, the stores and servers the tests reach.

Test modules and conftest files import shared helpers from here only, never from one
another; the fixtures that wrap these helpers live in the conftest files.
"""
