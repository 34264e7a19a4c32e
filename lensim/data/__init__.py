"""Training data: aligned (aberrated, sharp) pairs with their sensor positions."""
