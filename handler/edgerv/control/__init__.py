"""The planner's levers on a handler from outside it: never imports edgerv.handler."""
