"""Queries over the SQL schema, one module per aggregate. Functions take an
``AsyncSession``; the caller (a service) owns the transaction."""
