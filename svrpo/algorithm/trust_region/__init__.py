"""Natural-gradient machinery: conjugate gradient, Fisher/identity metrics, line search."""
